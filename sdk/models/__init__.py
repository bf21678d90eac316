"""Models shipped with the package (ONNX files with equipose metadata)."""
