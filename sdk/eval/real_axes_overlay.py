"""Overlay images of the real-data axis check: scene colour, poses, evaluated axes, the table normal, labels.

Convention: camera frame OpenCV (x right, y down, z forward), metres; images BGR uint8; angles in degrees.
"""
from __future__ import annotations

import numpy as np

__all__ = ["draw_overlay"]


def _scaled(image: np.ndarray, K: np.ndarray, width: int) -> tuple:
    """Resize ``image`` to ``width`` (if smaller than it is) and adapt ``K`` (pixel-centre convention)."""
    import cv2
    H, W = image.shape[:2]
    if not width or width >= W:
        return image.copy(), K.copy()
    s = width / W
    img = cv2.resize(image, (width, int(round(H * s))), interpolation=cv2.INTER_AREA)
    Ks = K.copy()
    Ks[0, 0], Ks[1, 1] = K[0, 0] * s, K[1, 1] * s
    Ks[0, 2], Ks[1, 2] = (K[0, 2] + 0.5) * s - 0.5, (K[1, 2] + 0.5) * s - 0.5
    return img, Ks


def _text(img, txt, org, scale=0.4, color=(255, 255, 255)):
    import cv2
    cv2.putText(img, txt, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 2, cv2.LINE_AA)
    cv2.putText(img, txt, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, 1, cv2.LINE_AA)


def draw_overlay(scene, plane, results: list, model_label: str, random_init: bool, width: int) -> np.ndarray:
    """BGR overlay: scene colour (or depth colour map), poses, table normal arrow, deviation labels.

    Convention: ``results`` [(object id, PoseResult or None, row dict)], metres / degrees, camera frame.
    """
    import cv2

    from equipose.runtime.overlay import depth_colormap, project
    base = scene.rgb if scene.rgb is not None else depth_colormap(scene.depth)
    img, K = _scaled(base, scene.K, width)
    valid = cv2.resize(scene.valid.astype(np.uint8), img.shape[1::-1], interpolation=cv2.INTER_NEAREST) > 0
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)[:, :, None] // 48 * 16          # outside the cloud: 6 dark greys
    img = np.where(valid[:, :, None], img // 8 * 8 + 4, grey).astype(np.uint8)  # inside: 32 levels (PNG ~2× smaller)
    for oid, res, row in results:
        if res is None:
            continue
        img = res.plot(img, K, thickness=1, label=False)
        if row.get("axis") is not None:                                         # the evaluated axis, ±6 cm
            ends, ok = project(res.translation[None] + np.outer([-0.06, 0.06], row["axis"]), K)
            if ok.all():
                cv2.line(img, tuple(int(round(x)) for x in ends[0]), tuple(int(round(x)) for x in ends[1]),
                         (255, 0, 255), 2, cv2.LINE_AA)
    c = plane.centroid
    uv, front = project(np.vstack([c, c + 0.10 * plane.normal]), K)             # 10 cm "up" arrow
    if front.all():
        p0, p1 = (tuple(int(round(x)) for x in uv[0]), tuple(int(round(x)) for x in uv[1]))
        cv2.arrowedLine(img, p0, p1, (0, 0, 0), 4, cv2.LINE_AA, tipLength=0.25)
        cv2.arrowedLine(img, p0, p1, (0, 255, 255), 2, cv2.LINE_AA, tipLength=0.25)
        _text(img, "up", (p1[0] + 4, p1[1]), 0.4, (0, 255, 255))
    for oid, res, row in results:                                              # labels last: drawn on top
        uv, front = project(np.asarray(row["centroid_m"])[None], K)             # at the object's point centroid
        if front[0]:
            u, v = int(round(uv[0, 0])), int(round(uv[0, 1]))
            txt = (f"#{oid} {row['deviation']:.0f}{row['pose'][0].upper()}" if res is not None else f"#{oid} error") + \
                f"  pca {row['baseline_deviation']:.0f}"
            _text(img, txt, (u - 30, v + 4))
    _text(img, f"{scene.name}  {model_label}" + ("  (RANDOM WEIGHTS)" if random_init else ""), (5, 14), 0.45)
    return img
