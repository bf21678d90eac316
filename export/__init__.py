"""equipose.export — torch → ONNX with the group convolutions as static Gather ops (needs the ``train`` extra).

``export_model`` / ``export_checkpoint`` / ``export_random_model`` write one self-describing ONNX file;
``quantize_int8`` writes the int8 copy; ``upgrade_model_file`` turns a format-1 file into a format-2 one;
``graph_rewrite.rewrite_model_file`` applies exact graph rewrites to a shipped file. torch is
imported only when an export runs.
"""
from equipose.export.onnx_export import (DEFAULT_OPSET, INPUT_NAME, OUTPUT_NAMES, export_checkpoint,  # noqa: F401
                                         export_model, export_random_model, op_type_counts, update_metadata,
                                         upgrade_model_file)
from equipose.models.int8 import int8_path_for, quantize_int8  # noqa: F401
