"""Length units given by name or as metres per unit (depth frames, model files).

Convention: a unit is "mm", "cm", "m" or a positive finite number of metres per stored unit; the result is metres per
unit (float). Names are exact strings: a number written as a string is not a unit here (parse it first).
"""
from __future__ import annotations

import math

__all__ = ["UNITS", "metres_per_unit"]

UNITS = {"mm": 1e-3, "m": 1.0, "cm": 1e-2}


def metres_per_unit(unit, name: str, error: type, stored: str = "stored unit") -> float:
    """Metres per ``unit``; a bad one raises ``error`` (an ``EquiposeError`` subclass) naming the argument ``name`` and,
    for a number, what one unit is (``stored``, e.g. "stored unit", "file unit")."""
    if isinstance(unit, str):
        if unit not in UNITS:
            raise error(f"{name} must be 'mm', 'm', 'cm' or metres per unit as a number, got {unit!r}")
        return UNITS[unit]
    try:
        s = float(unit)
    except (TypeError, ValueError):
        raise error(f"{name} must be 'mm', 'm', 'cm' or a positive number, got {unit!r}") from None
    if not (math.isfinite(s) and s > 0):
        raise error(f"{name} as a number is metres per {stored} and must be positive, got {s}")
    return s
