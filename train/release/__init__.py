"""Shipping a model from its recipe: ``python -m equipose.train.release MODEL [--recipe FILE] [--state DIR]
[--dry-run] [--skip-eval]``.

One TOML recipe per shipped model (``recipes/<model>.toml``, format in ``recipe``) says how
``sdk/models/<model>{,.int8}.onnx`` is made; ``steps`` turns it into the ``equipose`` CLI commands and ``python -m``
calls that calibrate, export, add the stages and evaluate, and runs them one by one.
"""
