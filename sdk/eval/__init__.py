"""Evaluation: every metric in one place — pose errors and table rows (``metrics``, with the metric registry),
real-data axis checks (``realdata``, ``real_axes``). Torch-free; the torch-side evaluation loop is
``equipose.train.evaluate``.
"""
from equipose.eval.metrics import (METRICS, register_metric, rotation_errors, row_keys, summarize, translation_errors,
                                   unregister_metric)

__all__ = ["METRICS", "register_metric", "unregister_metric", "row_keys", "summarize", "rotation_errors",
           "translation_errors"]
