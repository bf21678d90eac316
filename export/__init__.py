"""equipose.export — torch → ONNX with the group convolutions as static Gather ops (needs the ``train`` extra)."""
