"""``ModelSpec``: what the pipeline needs to know of a model file, decoded once from its metadata.

Convention: lengths in model units (``scale`` metres per unit); the calibration maps the network's learned frame to
the category frame, ``R_cat = R · δRᵀ``, ``t_cat = t − R_cat · δt`` (``equipose.runtime.hypotheses``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from equipose.runtime.hypotheses import parse_symmetry

__all__ = ["ModelSpec"]


@dataclass(frozen=True)
class ModelSpec:
    """Typed view of an equipose model's metadata (``equipose.core.metadata``).

    Attributes:
        name: the file's name (for messages); category; partial (trained on single views); num_points N;
        scale: metres per model unit; symmetry: the category's symmetry string; random_init.
        calibration: (δR [3, 3], δt [3]) of the plain network; refine_calibration: the calibration for the ICP
            re-scoring with its settings ({"k", "iters", "copies", "rotation", "translation", "visibility",
            "polish", "densify"}), or None.
        metadata: the whole decoded metadata (stages read their own optional keys from it).
    """
    name: str
    category: str
    partial: bool
    num_points: int
    scale: float
    symmetry: str
    random_init: bool
    calibration: tuple
    refine_calibration: dict | None
    metadata: dict

    @classmethod
    def from_metadata(cls, metadata: dict, name: str = "model") -> "ModelSpec":
        """Build the spec from ``decode_metadata``'s output. Raises ``MetadataError`` for an unsupported symmetry."""
        parse_symmetry(str(metadata["symmetry"]))
        return cls(name=name, category=str(metadata["category"]), partial=bool(metadata["partial"]),
                   num_points=int(metadata["num_points"]), scale=float(metadata["scale"]),
                   symmetry=str(metadata["symmetry"]), random_init=bool(metadata["random_init"]),
                   calibration=(np.asarray(metadata["calibration_rotation"], np.float64),
                                np.asarray(metadata["calibration_translation"], np.float64)),
                   refine_calibration=metadata.get("refine_calibration"), metadata=metadata)

    def get(self, key: str):
        """An optional metadata key's decoded value, or None."""
        return self.metadata.get(key)
