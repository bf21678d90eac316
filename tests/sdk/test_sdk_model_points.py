"""Model points from files (``equipose.core.model_points``) and ``equipose predict --model-points`` (instance mode)."""
import json

import numpy as np
import pytest

from equipose import errors
from equipose.cli import main
from equipose.core.model_points import MESH_POINTS, load_model_points, sample_surface

CUBE_V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)   # unit cube corners
CUBE_QUADS = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]


def _on_cube_surface(p):
    """Each point lies on a face of the unit cube: one coordinate is 0 or 1, all within [0, 1]."""
    inside = np.all((p > -1e-9) & (p < 1 + 1e-9), axis=1)
    on_face = np.any(np.isclose(p, 0.0) | np.isclose(p, 1.0), axis=1)
    return bool(np.all(inside & on_face))


def test_point_files_and_units(tmp_path):
    pts = np.random.default_rng(0).uniform(-50, 50, (300, 3))                   # millimetres
    (tmp_path / "a.xyz").write_text("# x y z\n" + "\n".join(" ".join(f"{v:.6f}" for v in p) + " 0.5" for p in pts))
    (tmp_path / "a.csv").write_text("\n".join(",".join(f"{v:.6f}" for v in p) for p in pts))
    np.save(tmp_path / "a.npy", pts)
    for name in ("a.xyz", "a.csv", "a.npy"):
        got = load_model_points(tmp_path / name, "mm")
        assert got.shape == (300, 3) and np.allclose(got, pts / 1000, atol=1e-9), name
    assert np.allclose(load_model_points(tmp_path / "a.npy", 0.001), pts / 1000)


def test_pcd_points(tmp_path):
    from pypcd4 import PointCloud
    pts = np.random.default_rng(1).normal(size=(200, 3)).astype(np.float32)
    PointCloud.from_xyz_points(pts).save(str(tmp_path / "a.pcd"))
    assert np.allclose(load_model_points(tmp_path / "a.pcd"), pts, atol=1e-6)


def test_meshes_are_sampled_on_their_surface(tmp_path):
    obj = "\n".join(f"v {x} {y} {z}" for x, y, z in CUBE_V) + "\n" + \
        "\n".join("f " + " ".join(f"{i + 1}/1/1" for i in q) for q in CUBE_QUADS)
    (tmp_path / "c.obj").write_text(obj)
    ply_a = ["ply", "format ascii 1.0", "element vertex 8", "property float x", "property float y",
             "property float z", "element face 6", "property list uchar int vertex_indices", "end_header"]
    ply_a += [" ".join(map(str, v)) for v in CUBE_V] + ["4 " + " ".join(map(str, q)) for q in CUBE_QUADS]
    (tmp_path / "c.ply").write_text("\n".join(ply_a) + "\n")
    tris = np.array([[q[0], q[i], q[i + 1]] for q in CUBE_QUADS for i in (1, 2)])
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty double x\nproperty double y\n"
            "property double z\nelement face 12\nproperty list uchar int vertex_indices\nend_header\n").encode()
    faces = np.zeros(12, np.dtype([("n", "u1"), ("i", "<i4", 3)]))
    faces["n"], faces["i"] = 3, tris
    (tmp_path / "b.ply").write_bytes(head + CUBE_V.astype("<f8").tobytes() + faces.tobytes())
    for name in ("c.obj", "c.ply", "b.ply"):
        p = load_model_points(tmp_path / name)
        assert p.shape == (MESH_POINTS, 3) and _on_cube_surface(p), name
        assert np.all(np.abs(p.mean(0) - 0.5) < 0.03), name                     # spread by area over all faces
    assert np.array_equal(load_model_points(tmp_path / "c.obj"), load_model_points(tmp_path / "c.obj"))
    assert np.allclose(np.sort(load_model_points(tmp_path / "c.ply"), 0), np.sort(sample_surface(CUBE_V, tris), 0))


def test_bad_files_say_what_is_wrong(tmp_path):
    (tmp_path / "bad.xyz").write_text("1 2 3\n4 five 6\n")
    (tmp_path / "short.txt").write_text("1 2\n")
    (tmp_path / "x.stl").write_text("solid")
    (tmp_path / "nof.obj").write_text("v 0 0 0\nv 1 0 0\n")
    (tmp_path / "t.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty float x\n"
                                     b"property float y\nproperty float z\nend_header\n" + b"\0" * 10)
    cases = {"bad.xyz": "line 2", "short.txt": "need x y z", "x.stl": "unknown file type", "nof.obj": "faces",
             "t.ply": "ends inside", "missing.xyz": "not a file"}
    for name, words in cases.items():
        with pytest.raises(errors.InvalidPointsError, match=words):
            load_model_points(tmp_path / name)
    with pytest.raises(errors.InvalidPointsError, match="unit"):
        load_model_points(tmp_path / "bad.xyz", "inch")
    assert issubclass(errors.InvalidPointsError, ValueError)


def test_predict_model_points_runs_instance_mode(tmp_path, capsys, data_root):
    d = data_root / "ycb_posecnn"
    depth = d / "demo_images" / "000001-depth.png"
    K = "1066.778,1067.487,312.9869,241.3109"
    rc = main(["predict", "-m", "can-tabletop", "--depth", str(depth), "--intrinsics", K, "--depth-unit", "0.0001",
               "--box", "395,245,70,135", "--model-points", str(d / "models" / "005_tomato_soup_can" / "points.xyz"),
               "--json"])
    assert rc == 0
    rec = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    t = np.asarray(rec["poses"][0]["translation_m"])                           # the soup can's model origin
    assert np.allclose(t, [0.099, 0.054, 0.919], atol=0.01)                     # docs/results/real: 0.92 m away
    rc = main(["predict", "-m", "can-tabletop", "--depth", str(depth), "--intrinsics", K, "--box", "395,245,70,135",
               "--model-points", str(tmp_path / "none.xyz")])
    assert rc == 2 and "not a file" in capsys.readouterr().err
