"""Real-data evaluation on annotated RGB-D layouts (``equipose eval --dataset``): readers for YCB-Video (``ycbv``),
BOP (``bop``) and GraspNet (``graspnet``) into one record (``frames.GTFrame``), object-set mappings into the equipose
categories (``mapping`` + the shipped ``*.toml``) and the evaluation loop (``run``). Torch-free.
"""
from equipose.eval.datasets.frames import GTFrame, GTObject, mask_box
from equipose.eval.datasets.mapping import ObjectEntry, load_mapping
from equipose.eval.datasets.run import evaluate_dataset, format_table, open_frames, score_pose, write_json

__all__ = ["GTFrame", "GTObject", "mask_box", "ObjectEntry", "load_mapping", "evaluate_dataset", "format_table",
           "open_frames", "score_pose", "write_json"]
