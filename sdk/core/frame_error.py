"""``FrameError``: the record a stream yields for a frame (or one object in it) that could not be processed.

Sources yield it for a bad frame and carry on; the runtime yields it for a frame or object whose prediction failed.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FrameError"]


@dataclass
class FrameError:
    """A frame (or one object in it) that could not be processed; streams carry on after it.

    Attributes: frame_index, object_id (None = whole frame), error (exception class name), message.
    """
    frame_index: int
    error: str
    message: str
    object_id: int | None = None

    @classmethod
    def from_exception(cls, frame_index: int, exc: BaseException, object_id=None) -> "FrameError":
        return cls(frame_index=frame_index, error=type(exc).__name__, message=str(exc), object_id=object_id)

    def to_dict(self) -> dict:
        return {"frame_index": self.frame_index, "object_id": self.object_id, "error": self.error,
                "message": self.message}
