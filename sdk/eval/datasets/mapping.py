"""Object-set mapping files (``ycbv.toml``, ``graspnet.toml``, shipped beside this module): which equipose model
evaluates a dataset object, its symmetry, and the rotation from the object model's frame into the category frame.

Convention:
    ``x_category = R_model_to_category @ (x_model − centre_model_m)`` (metres). A ground-truth pose model → camera
    (``x_cam = R @ x_model + t``) becomes the category pose ``R_cat = R @ R_model_to_categoryᵀ`` with origin
    ``c_cam = R @ centre_model_m + t`` — what ``PoseResult.rotation`` / ``.translation`` estimate. ``symmetry`` is
    "none" or "continuous:<x|y|z>"; ``unsigned_axis`` folds the axis error (up ≡ down). An entry with an empty
    ``category`` is skipped with its ``skip_reason``.
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.symmetry import parse_symmetry

__all__ = ["ObjectEntry", "load_mapping", "mapping_path", "DEFAULT_MAPPING"]

HERE = pathlib.Path(__file__).resolve().parent
DEFAULT_MAPPING = {"ycbv": "ycbv.toml", "bop": "ycbv.toml", "graspnet": "graspnet.toml"}


@dataclass(frozen=True)
class ObjectEntry:
    """One mapped object. Convention: see the module docstring; ``R_model_to_category`` [3, 3] (orthonormalised on
    load), ``centre_model_m`` [3] metres; ``category`` None = skipped (``skip_reason``)."""
    key: int
    name: str
    category: str | None
    model: str | None
    symmetry: str = "none"
    unsigned_axis: bool = False
    R_model_to_category: np.ndarray = None
    centre_model_m: np.ndarray = None
    skip_reason: str | None = None

    def category_pose(self, R, t) -> tuple:
        """Ground-truth model → camera pose (R [3, 3], t [3] metres) → (R_cat [3, 3], c_cam [3] metres): the pose of
        the category frame in the camera, comparable with ``PoseResult.rotation`` / ``.translation``."""
        R = np.asarray(R, np.float64)
        t = np.asarray(t, np.float64)
        if R.shape != (3, 3) or t.shape != (3,):
            raise ConfigError(f"category_pose needs R [3, 3] and t [3], got {R.shape} and {t.shape}")
        return R @ self.R_model_to_category.T, R @ self.centre_model_m + t


def mapping_path(name_or_path) -> pathlib.Path:
    """A shipped mapping by dataset name ("ycbv", "bop", "graspnet") or a TOML path; raises ``ConfigError``."""
    s = str(name_or_path)
    p = HERE / DEFAULT_MAPPING[s] if s in DEFAULT_MAPPING else pathlib.Path(s)
    if not p.is_file():
        raise ConfigError(f"mapping {s!r}: no such file; give one of {sorted(DEFAULT_MAPPING)} or a .toml path")
    return p


def _rotation(value, where: str) -> np.ndarray:
    R = np.asarray(value, np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ConfigError(f"{where}: R_model_to_category must be a 3 x 3 list of numbers, got shape {R.shape}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0.99:
        raise ConfigError(f"{where}: R_model_to_category is not a rotation (R Rᵀ ≠ I or det ≠ +1)")
    u, _, vt = np.linalg.svd(R)                                                 # 4-decimal TOML → exact rotation
    return u @ vt


def load_mapping(name_or_path) -> dict:
    """{object key (int): ObjectEntry} of a mapping TOML. Convention: see the module docstring and ``ycbv.toml``.
    Raises ``ConfigError`` naming the entry and field that is wrong."""
    try:
        import tomllib
    except ModuleNotFoundError:                                                 # Python 3.10
        import tomli as tomllib
    p = mapping_path(name_or_path)
    try:
        doc = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"mapping {p}: not valid TOML ({e})") from None
    objects = doc.get("objects")
    if not isinstance(objects, dict) or not objects:
        raise ConfigError(f"mapping {p}: needs [objects.<id>] tables")
    out = {}
    for key, e in objects.items():
        where = f"mapping {p.name} [objects.{key}]"
        try:
            k = int(key)
        except ValueError:
            raise ConfigError(f"{where}: object keys are integer ids") from None
        if not isinstance(e, dict) or "name" not in e:
            raise ConfigError(f"{where}: needs at least name = \"...\"")
        cat = e.get("category") or None
        if cat is None:
            out[k] = ObjectEntry(k, str(e["name"]), None, None, skip_reason=e.get("skip_reason", "no category"))
            continue
        miss = [f for f in ("model", "symmetry", "R_model_to_category", "centre_model_m") if f not in e]
        if miss:
            raise ConfigError(f"{where}: a mapped object needs {miss}")
        sym = str(e["symmetry"])
        kind, _, _ = parse_symmetry(sym)
        if kind == "discrete":
            raise ConfigError(f"{where}: symmetry {sym!r}: the dataset metrics read 'none' or 'continuous:<axis>'")
        c = np.asarray(e["centre_model_m"], np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ConfigError(f"{where}: centre_model_m must be 3 numbers (metres), got {e['centre_model_m']!r}")
        out[k] = ObjectEntry(k, str(e["name"]), str(cat), str(e["model"]), sym, bool(e.get("unsigned_axis", False)),
                             _rotation(e["R_model_to_category"], where), c)
    return out
