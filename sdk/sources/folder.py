"""PNG folder recordings: 16-bit PNG depth, optional colour, one intrinsics JSON.

Convention (layout):
    DIR/intrinsics.json   {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "width": W, "height": H, "depth_unit": "mm"}
                          (``depth_unit`` "mm" = uint16 millimetres; or metres per stored unit as a number)
    DIR/depth/NNNNNN.png  uint16 [H, W], 0 = invalid (read with cv2.IMREAD_UNCHANGED — never the default flag)
    DIR/rgb/NNNNNN.png    optional BGR colour registered to the depth (same stem), .png or .jpg
    DIR/timestamps.json   optional {"NNNNNN": seconds}
"""
from __future__ import annotations

import json
import pathlib

import numpy as np

from equipose.core.errors import SourceError
from equipose.core.frame_error import FrameError
from equipose.sources.base import Frame, FrameSource, register_source

__all__ = ["FolderSource", "FolderWriter", "read_intrinsics", "write_intrinsics"]


def read_intrinsics(path) -> dict:
    """Read ``intrinsics.json`` → {"K": [3, 3] float64, "image_size": (W, H), "depth_unit": ...}. Raises ``SourceError``."""
    path = pathlib.Path(path)
    try:
        d = json.loads(path.read_text())
        K = np.asarray(d["K"], dtype=np.float64)
        size = (int(d["width"]), int(d["height"]))
    except FileNotFoundError:
        raise SourceError(f"{path} not found; a PNG depth folder needs intrinsics.json with K, width, height") from None
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as e:
        raise SourceError(f"{path} is malformed ({type(e).__name__}: {e}); expected "
                          '{"K": [[fx,0,cx],[0,fy,cy],[0,0,1]], "width": W, "height": H, "depth_unit": "mm"}') from None
    if K.shape != (3, 3):
        raise SourceError(f"{path}: K must be 3×3, got shape {K.shape}")
    return {"K": K, "image_size": size, "depth_unit": d.get("depth_unit", "mm")}


def write_intrinsics(path, K, width: int, height: int, depth_unit="mm", **extra):
    """Write ``intrinsics.json`` (see the module convention)."""
    d = {"K": np.asarray(K, np.float64).reshape(3, 3).tolist(), "width": int(width), "height": int(height),
         "depth_unit": depth_unit, **extra}
    pathlib.Path(path).write_text(json.dumps(d, indent=1))


@register_source("folder", folder=lambda p: (p / "intrinsics.json").is_file())
class FolderSource(FrameSource):
    """Frames from a PNG folder (layout in the module doc), in file-name order.

    A frame whose PNG cannot be read or is not 16-bit is yielded as a ``FrameError`` and the iteration continues.
    """

    def __init__(self, path, *, loop: bool = False):
        import cv2  # noqa: F401  (fail early if opencv is missing)
        self.path = pathlib.Path(path)
        if not self.path.is_dir():
            raise SourceError(f"{self.path} is not a folder; FolderSource expects DIR/intrinsics.json + DIR/depth/*.png")
        self.intrinsics = read_intrinsics(self.path / "intrinsics.json")
        self.depth_files = sorted((self.path / "depth").glob("*.png"))
        if not self.depth_files:
            raise SourceError(f"{self.path / 'depth'} holds no .png depth frames")
        ts = self.path / "timestamps.json"
        self.timestamps = json.loads(ts.read_text()) if ts.is_file() else {}
        self.loop = loop

    def __len__(self):
        return len(self.depth_files)

    def _rgb_for(self, stem: str):
        import cv2
        for ext in (".png", ".jpg", ".jpeg"):
            p = self.path / "rgb" / (stem + ext)
            if p.is_file():
                return cv2.imread(str(p), cv2.IMREAD_COLOR)
        return None

    def read(self, i: int):
        """Frame ``i`` (or a ``FrameError`` record if its depth PNG is unreadable / not 16-bit)."""
        import cv2
        f = self.depth_files[i]
        depth = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)                        # [H, W] uint16
        if depth is None:
            return FrameError(i, "SourceError", f"{f} could not be read as an image")
        if depth.dtype != np.uint16 or depth.ndim != 2:
            return FrameError(i, "DepthDtypeError", f"{f} is {depth.dtype} {depth.shape}, expected a single-channel "
                              "16-bit PNG of millimetres (cv2.imwrite(path, depth.astype(np.uint16)))")
        return Frame(depth=depth, K=self.intrinsics["K"], depth_unit=self.intrinsics["depth_unit"],
                     rgb=self._rgb_for(f.stem), index=i, timestamp=self.timestamps.get(f.stem),
                     image_size=self.intrinsics["image_size"], name=f.stem)

    def __iter__(self):
        while True:
            for i in range(len(self.depth_files)):
                yield self.read(i)
            if not self.loop:
                return


class FolderWriter:
    """Write frames as a PNG folder (the layout FolderSource reads). Use as a context manager or call ``close()``."""

    def __init__(self, path, *, overwrite: bool = False):
        self.path = pathlib.Path(path)
        if self.path.exists() and any(self.path.iterdir()) and not overwrite:
            raise SourceError(f"{self.path} exists and is not empty; choose a new folder or pass overwrite=True")
        (self.path / "depth").mkdir(parents=True, exist_ok=True)
        self.count, self.timestamps, self._intr = 0, {}, None

    def write(self, frame: Frame):
        """Append one frame. Depth must be uint16 millimetres (``depth_unit="mm"``)."""
        import cv2
        depth = np.asarray(frame.depth)
        if depth.dtype != np.uint16 or frame.depth_unit != "mm":
            raise SourceError(f"FolderWriter stores uint16 millimetres; got {depth.dtype} with depth_unit "
                              f"{frame.depth_unit!r} — convert first: (depth_m * 1000).round().astype(np.uint16)")
        H, W = depth.shape
        size = tuple(frame.image_size) if frame.image_size is not None else (W, H)
        intr = (np.asarray(frame.K, np.float64).round(9).tolist(), size)
        if self._intr is None:
            write_intrinsics(self.path / "intrinsics.json", frame.K, size[0], size[1], "mm")
            self._intr = intr
        elif intr != self._intr:
            raise SourceError("FolderWriter keeps one intrinsics.json; the intrinsics changed mid-recording — record "
                              "to .mcap (per-frame intrinsics) instead")
        stem = f"{self.count:06d}"
        if not cv2.imwrite(str(self.path / "depth" / f"{stem}.png"), depth):
            raise SourceError(f"could not write {self.path / 'depth' / (stem + '.png')}")
        if frame.rgb is not None:
            (self.path / "rgb").mkdir(exist_ok=True)
            cv2.imwrite(str(self.path / "rgb" / f"{stem}.png"), np.asarray(frame.rgb))
        if frame.timestamp is not None:
            self.timestamps[stem] = float(frame.timestamp)
        self.count += 1

    def close(self):
        if self.timestamps:
            (self.path / "timestamps.json").write_text(json.dumps(self.timestamps, indent=1))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
