"""Camera intrinsics: validate a pinhole ``K`` against a frame and rescale it to the frame's size.

Convention:
    Intrinsics ``K`` are ``[3, 3]`` (OpenCV pinhole ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels, pixel centres at
    integer coordinates). ``image_size=(W, H)`` is the size ``K`` was calibrated for; when the frame has another size
    of the same aspect ratio, ``K`` is rescaled. Frame shapes are ``(H, W)``.

Used by the sources (to store ``K`` for the size they record) and by ``equipose.preprocess`` (which re-exports it).
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import IntrinsicsError

__all__ = ["FOCAL_RANGE", "CENTRE_TOLERANCE", "check_intrinsics"]

FOCAL_RANGE = (0.05, 50.0)        # fx, fy in units of the frame's larger side: fields of view of ~169° down to ~1°
CENTRE_TOLERANCE = 0.3            # principal point within ± this fraction of the frame size from its centre


def check_intrinsics(K, depth_shape, image_size=None) -> np.ndarray:
    """Validate intrinsics against a frame and rescale them to it.

    Convention: ``K`` [3, 3] pinhole ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (skew allowed); ``depth_shape`` (H, W);
    ``image_size`` (W, H) that ``K`` belongs to, or None for "the frame's own size".
    Returns [3, 3] float64 K for the frame. Raises ``IntrinsicsError``.
    """
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise IntrinsicsError("K must be a numeric 3×3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]") from None
    if K.shape != (3, 3):
        raise IntrinsicsError(f"K must be 3×3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got shape {K.shape}"
                              + (" (pass np.array(K).reshape(3, 3) for a flat list of 9)" if K.size == 9 else ""))
    if not np.all(np.isfinite(K)):
        raise IntrinsicsError("K contains NaN or Inf")
    last_row = abs(K[2, 0]) <= 1e-8 and abs(K[2, 1]) <= 1e-8 and abs(K[2, 2] - 1.0) <= 1e-8 + 1e-5   # allclose
    if not (K[0, 0] > 0 and K[1, 1] > 0) or not last_row or K[1, 0] != 0:
        raise IntrinsicsError(f"K is not a pinhole matrix (need fx, fy > 0 and last row 0 0 1): {K.tolist()}")
    H, W = int(depth_shape[0]), int(depth_shape[1])
    K = K.copy()
    if image_size is not None:
        try:
            w0, h0 = (int(v) for v in image_size)
        except (TypeError, ValueError):
            raise IntrinsicsError(f"image_size must be (width, height), got {image_size!r}") from None
        if w0 <= 0 or h0 <= 0:
            raise IntrinsicsError(f"image_size must be positive (width, height), got {image_size!r}")
        if (w0, h0) != (W, H):
            sx, sy = W / w0, H / h0
            if abs(sx - sy) > 0.01 * max(sx, sy):
                raise IntrinsicsError(
                    f"K belongs to a {w0}×{h0} image but the depth frame is {W}×{H} (different aspect ratio); a crop "
                    "cannot be undone from the size alone — pass the intrinsics of the depth frame itself")
            # pixel centres at integer coordinates: x' = (x + 0.5) · s − 0.5
            K[0, :2] *= sx                                                      # fx, skew
            K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
            K[1, 1] *= sy
            K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    fx, fy = K[0, 0], K[1, 1]
    if not (FOCAL_RANGE[0] * max(W, H) <= min(fx, fy) and max(fx, fy) <= FOCAL_RANGE[1] * max(W, H)) \
            or not 0.2 <= fx / fy <= 5.0:
        raise IntrinsicsError(
            f"focal lengths fx={fx:.4g}, fy={fy:.4g} px are implausible for a {W}×{H} frame (a pinhole camera has "
            f"{FOCAL_RANGE[0]:g}–{FOCAL_RANGE[1]:g} × the image size, fx ≈ fy): K must be in pixels of this frame, "
            "not normalised or in millimetres")
    if abs(K[0, 2] - (W - 1) / 2) > CENTRE_TOLERANCE * W or abs(K[1, 2] - (H - 1) / 2) > CENTRE_TOLERANCE * H:
        raise IntrinsicsError(
            f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) is far from the centre of the {W}×{H} depth frame: K "
            "belongs to another resolution. Pass image_size=(W, H) of the image K was calibrated for (if this frame "
            "is a crop, shift cx, cy by the crop offset)")
    if not (0 < K[0, 2] < W - 1 and 0 < K[1, 2] < H - 1):
        raise IntrinsicsError(
            f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) lies outside the {W}×{H} depth frame: K does not match the "
            "image size. Pass image_size=(W, H) of the image K was calibrated for, or the intrinsics of this frame")
    return K
