"""CLI subcommands of the SDK (runtime side: no torch)."""
from __future__ import annotations

from equipose.core.errors import ConfigError

__all__ = ["stage_options"]


def stage_options(text):
    """``--stages`` JSON → {stage: options} for ``PoseEstimator(stages=...)`` (None when not given)."""
    if not text:
        return None
    import json
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(f"--stages must be JSON like '{{\"rescore\": {{\"iters\": 10}}}}': {e}") from None
    if not isinstance(value, dict):
        raise ConfigError(f"--stages must be a JSON object of stage options, got {text!r}")
    return value
