"""OpenCV drawing of poses: axes, oriented 3D boxes, depth colourisation.

Convention: images are BGR uint8 [H, W, 3]; ``K`` [3, 3] is the intrinsics of the image drawn on; 3D points are
metres in the OpenCV camera frame. Nothing is drawn for points behind the camera (z ≤ 1 cm).
"""
from __future__ import annotations

import numpy as np

__all__ = ["to_bgr", "depth_colormap", "project", "draw_pose", "draw_poses", "pose_label", "place_label", "draw_mask"]

_BOX_EDGES = [(0, 1), (0, 2), (1, 3), (2, 3), (4, 5), (4, 6), (5, 7), (6, 7), (0, 4), (1, 5), (2, 6), (3, 7)]


def depth_colormap(depth, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """[H, W] depth (any unit) → [H, W, 3] BGR uint8 (turbo colour map, invalid = black)."""
    import cv2
    d = np.asarray(depth, np.float64)
    valid = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape + (3,), np.uint8)
    if not valid.any():
        return out
    lo = np.percentile(d[valid], 2) if lo is None else lo
    hi = np.percentile(d[valid], 98) if hi is None else hi
    u8 = np.clip((d - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(u8, cv2.COLORMAP_TURBO)
    out[~valid] = 0
    return out


def to_bgr(image) -> np.ndarray:
    """Any image-like array → a fresh BGR uint8 [H, W, 3] (grey replicated; 16-bit/float depth colourised)."""
    img = np.asarray(image)
    if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 1):
        img = img.reshape(img.shape[:2])
        if img.dtype != np.uint8:
            return depth_colormap(img)
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be [H, W], [H, W, 3] or [H, W, 4], got {img.shape}")
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img.copy())


def project(points, K) -> tuple:
    """[P, 3] metres (camera frame) → ([P, 2] float pixel (u, v), [P] bool in front of the camera)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    K = np.asarray(K, np.float64)
    front = p[:, 2] > 0.01
    z = np.where(front, p[:, 2], 1.0)
    uv = np.stack([K[0, 0] * p[:, 0] / z + K[0, 1] * p[:, 1] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]], 1)
    return uv, front


def draw_mask(image, mask, color=(255, 0, 255), alpha: float = 0.35) -> np.ndarray:
    """Blend a [H, W] bool mask onto a BGR image (returns a new image)."""
    img = to_bgr(image)
    m = np.asarray(mask, bool)
    img[m] = (img[m] * (1 - alpha) + np.asarray(color) * alpha).astype(np.uint8)
    return img


def _outlined_text(img, text: str, org, color) -> None:
    """``text`` at pixel ``org`` in ``color`` with a black outline (readable on any background)."""
    import cv2
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1, cv2.LINE_AA)


def draw_pose(image, K, result, *, axis_length: float | None = None, color=(0, 255, 0), thickness: int = 2,
              label: bool = True) -> np.ndarray:
    """Axes (x red, y green, z blue) + oriented 3D box of a ``PoseResult`` on a copy of ``image``; for a model with a
    handle, a longer arrow along the handle direction labelled "handle" (orange when seen, grey "handle?" if not)."""
    import cv2
    img = to_bgr(image)
    R, t = np.asarray(result.rotation), np.asarray(result.translation)
    corners = result.box_corners()                                              # [8, 3]
    uv, front = project(corners, K)
    ipt = lambda q: (int(round(q[0])), int(round(q[1])))                      # noqa: E731
    for a, b in _BOX_EDGES:
        if front[a] and front[b]:
            cv2.line(img, ipt(uv[a]), ipt(uv[b]), color, thickness, cv2.LINE_AA)
    if axis_length is None:
        mn, mx = result.extent()
        axis_length = 0.6 * float(np.max(mx - mn)) if np.all(np.isfinite(mx - mn)) else 0.05
        axis_length = max(axis_length, 0.01)
    ends = t[None] + axis_length * R.T                                          # [3, 3] rows = axis tips
    uv_axes, f_axes = project(np.vstack([t[None], ends]), K)
    if f_axes[0]:
        for k, col in enumerate([(0, 0, 255), (0, 255, 0), (255, 0, 0)]):
            if f_axes[k + 1]:
                cv2.line(img, ipt(uv_axes[0]), ipt(uv_axes[k + 1]), col, thickness + 1, cv2.LINE_AA)
    hd = getattr(result, "handle_direction", None)
    if hd is not None and f_axes[0]:                                            # the handle axis, labelled
        tip, f_tip = project((t + 1.4 * axis_length * np.asarray(hd))[None], K)
        if f_tip[0]:
            col = (0, 215, 255) if result.handle_visible else (160, 160, 160)
            cv2.arrowedLine(img, ipt(uv_axes[0]), ipt(tip[0]), col, thickness + 1, cv2.LINE_AA, tipLength=0.15)
            _outlined_text(img, "handle" if result.handle_visible else "handle?", ipt(tip[0] + np.array([4, 4])), col)
    if label and f_axes[0]:
        _outlined_text(img, pose_label(result), ipt(uv_axes[0] + np.array([6, -6])), (255, 255, 255))
    return img


def pose_label(result) -> str:
    """One line saying what a result is and how sure: "#3 mug conf 0.42 AMBIGUOUS (handle hidden)", "car conf 0.61
    turned? 0.38 AMBIGUOUS (may be turned)" (with a ``flip_risk``)."""
    hidden = getattr(result, "handle_visible", None) is False                   # (that also sets ambiguous)
    flag = " AMBIGUOUS (handle hidden)" if hidden else (" AMBIGUOUS (may be turned)" if result.ambiguous else "")
    risk = getattr(result, "flip_risk", None)
    txt = f"{result.category or 'object'} conf {result.confidence:.2f}" + \
        ("" if risk is None else f" turned? {risk:.2f}") + flag
    return txt if result.object_id is None else f"#{result.object_id} {txt}"


def place_label(anchor, size, shape, taken: list) -> list:
    """Where a label of ``size`` (w, h) pixels goes: up and right of ``anchor`` (u, v), inside the image ``shape``
    (H, W), stepped past every box in ``taken`` ([x0, y0, x1, y1] each) that it would overlap. Returns its box."""
    w, h = size
    H, W = shape
    x0 = int(np.clip(anchor[0] + 10, 0, max(W - w, 0)))
    y0 = int(np.clip(anchor[1] - h - 8, 0, max(H - h, 0)))
    for _ in range(4 * len(taken) + 4):
        box = [x0, y0, x0 + w, y0 + h]
        hit = next((b for b in taken if box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3]), None)
        if hit is None:
            return box
        y0 = hit[3] + 2 if hit[3] + 2 + h <= H else max(0, hit[1] - h - 2)
    return box


_LEGEND = ["axes: x red, y green, z blue; box: the shape's extent",
           "conf: the estimated chance that the pose is right",
           "AMBIGUOUS: another pose fits about as well"]


def draw_poses(image, K, results, *, legend: bool = True, thickness: int = 2) -> np.ndarray:
    """Every ``PoseResult`` of a frame on a copy of ``image``: boxes and axes first, then one label per object placed
    where it overlaps no other label (tied to its object by a thin line), and a legend in the top-left corner.

    Convention: ``image`` [H, W, 3] BGR uint8 (or depth, colourised); ``K`` [3, 3] of that image."""
    import cv2
    img = to_bgr(image)
    for r in results:
        img = draw_pose(img, K, r, thickness=thickness, label=False)
    taken = []                                                                  # [x0, y0, x1, y1] placed boxes
    H, W = img.shape[:2]
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    if legend:
        y = 6
        for line in _LEGEND:
            (w, h), _ = cv2.getTextSize(line, font, 0.45, 1)
            cv2.rectangle(img, (4, y), (12 + w, y + h + 8), (0, 0, 0), -1)
            cv2.putText(img, line, (8, y + h + 3), font, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            y += h + 8
        taken.append([0, 0, 16 + max(cv2.getTextSize(t, font, 0.45, 1)[0][0] for t in _LEGEND), y])
    for r in results:
        (uv,), (front,) = project(np.asarray(r.translation)[None], K)
        if not front:
            continue
        text = pose_label(r)
        (w, h), base = cv2.getTextSize(text, font, scale, 1)
        box = place_label(uv, (w + 6, h + base + 6), (H, W), taken)
        taken.append(box)
        colour = (0, 200, 255) if r.ambiguous else (0, 220, 0)
        anchor = (int(round(uv[0])), int(round(uv[1])))
        cv2.line(img, anchor, (box[0], (box[1] + box[3]) // 2), colour, 1, cv2.LINE_AA)
        cv2.rectangle(img, (box[0], box[1]), (box[2], box[3]), (0, 0, 0), -1)
        cv2.rectangle(img, (box[0], box[1]), (box[2], box[3]), colour, 1)
        cv2.putText(img, text, (box[0] + 3, box[3] - base - 3), font, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return img
