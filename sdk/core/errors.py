"""Typed errors of the equipose SDK. Every one subclasses ``ValueError`` (via ``EquiposeError``) and says what was
wrong and what to do about it."""
from __future__ import annotations

__all__ = [
    "EquiposeError", "DepthError", "EmptyDepthError", "DepthDtypeError", "DepthUnitError", "IntrinsicsError",
    "RegionError", "TooFewPointsError", "InvalidPointsError", "ModelFormatError", "ModelVersionError",
    "MetadataError", "SourceError", "ConfigError",
]


class EquiposeError(ValueError):
    """Base class of every equipose input error."""


class DepthError(EquiposeError):
    """The depth frame cannot be used."""


class EmptyDepthError(DepthError):
    """The depth frame (or the region of interest) holds no valid depth."""


class DepthDtypeError(DepthError):
    """Wrong depth dtype or layout (e.g. uint8 from ``cv2.imread`` without ``IMREAD_UNCHANGED``)."""


class DepthUnitError(DepthError):
    """Depth values are implausible for the declared unit."""


class IntrinsicsError(EquiposeError):
    """Camera intrinsics are malformed or do not match the image."""


class RegionError(EquiposeError):
    """The box or mask selecting the object is outside the image or empty."""


class TooFewPointsError(EquiposeError):
    """Fewer points than the model can use survived the crop."""


class InvalidPointsError(EquiposeError):
    """Points contain NaN/Inf or have the wrong shape."""


class ModelFormatError(EquiposeError):
    """The file is not an ONNX model, or not an equipose model."""


class ModelVersionError(ModelFormatError):
    """The model's metadata format version is not supported by this SDK."""


class MetadataError(ModelFormatError):
    """A required metadata key is missing or malformed."""


class SourceError(EquiposeError):
    """A frame source (camera, recording, folder) cannot be opened or read."""


class ConfigError(EquiposeError):
    """A configuration value is invalid."""
