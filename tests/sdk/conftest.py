"""Fixtures of the SDK runtime tests: one exported random-weight ``tiny`` model per session, synthetic depth scenes."""
import os
import pathlib

import numpy as np
import pytest

os.environ.setdefault("DEPTHAI_LEVEL", "error")

H, W = 480, 640
K_VGA = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory) -> pathlib.Path:
    """A random-weight ``tiny`` model (256 points), category mug, partial, 0.25 m per unit (exported with torch)."""
    pytest.importorskip("torch")
    from equipose.export.onnx_export import export_random_model
    path = tmp_path_factory.mktemp("models") / "tiny_mug.onnx"
    export_random_model("tiny", path, partial=True, category="mug", scale=0.25, verify=False)
    return path


@pytest.fixture(scope="session")
def estimator(tiny_model):
    from equipose import PoseEstimator
    return PoseEstimator(tiny_model, threads=1)


def sphere_scene(centre=(0.0, 0.0, 0.8), radius=0.05, wall_mm=1500, K=K_VGA, shape=(H, W)):
    """uint16 mm depth of a sphere in front of a flat wall (ray-cast), and the boolean sphere mask."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    dirs = np.stack([(xx - K[0, 2]) / K[0, 0], (yy - K[1, 2]) / K[1, 1], np.ones_like(xx)], -1)  # [H, W, 3]
    c = np.asarray(centre, np.float64)
    a = (dirs ** 2).sum(-1)
    b = -2.0 * dirs @ c
    cc = c @ c - radius ** 2
    disc = b * b - 4 * a * cc
    hit = disc > 0
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)                           # z of the hit (dirs have z = 1)
    depth = np.full((h, w), wall_mm, np.uint16)
    depth[hit] = np.round(t[hit] * 1000).astype(np.uint16)
    return depth, hit


def tabletop_scene(K=K_VGA, shape=(H, W)):
    """uint16 mm depth of a table plane (tilted, 0.9 m ahead) with two boxes standing on it; returns depth and the
    two object masks (ground truth)."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    rx, ry = (xx - K[0, 2]) / K[0, 0], (yy - K[1, 2]) / K[1, 1]
    # table plane n·x = d through (0, 0.25, 0.9), normal tilted towards the camera (camera looks down ~16°)
    n = np.array([0.0, -0.96, -0.28]); n /= np.linalg.norm(n)
    d = float(n @ np.array([0.0, 0.25, 0.9]))
    z_table = d / (n[0] * rx + n[1] * ry + n[2])                                # z where each ray meets the plane
    depth_m = np.where((z_table > 0.2) & (z_table < 3.0), z_table, 0.0)
    masks = []
    for u0 in (180, 400):                                                       # two 70×90 px boxes standing on it
        v1 = 330                                                                # bottom row touches the table
        z_face = float(z_table[v1, u0 + 35]) - 0.02                              # front face 2 cm before the contact
        m = np.zeros((h, w), bool)
        m[v1 - 90:v1, u0:u0 + 70] = True
        depth_m = np.where(m, z_face, depth_m)
        masks.append(m)
    masks = [m & (depth_m > 0) for m in masks]
    return np.round(depth_m * 1000).astype(np.uint16), masks
