"""The network: ``EquiPoseNet`` (``model``) built from SO(3)-separable and quotient layers (``layers``,
``quotient``); function-preserving widening (``widen``); a checkpoint recovered from a shipped ONNX file
(``onnx_weights``)."""
