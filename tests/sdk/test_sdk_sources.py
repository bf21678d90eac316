"""Sources round-trip: PNG folder, depthai .mcap (host-only, synthetic RAW16), organized PCD; record command."""
import json

import numpy as np
import pytest

from conftest import K_VGA, sphere_scene
from equipose import errors
from equipose.runtime.result import FrameError
from equipose.sources import Frame, open_source


def frames(n=3, rgb=True):
    out = []
    for i in range(n):
        depth, _ = sphere_scene((0.01 * i, 0.0, 0.8), 0.05)
        depth[i, :7] = 0                                                        # make frames distinct
        col = np.full((480, 640, 3), (10 * i, 100, 200), np.uint8) if rgb else None
        out.append(Frame(depth=depth, K=K_VGA, rgb=col, index=i, timestamp=i / 10))
    return out


def test_png_folder_round_trip(tmp_path):
    from equipose.sources import FolderSource, FolderWriter
    src = frames()
    with FolderWriter(tmp_path / "rec") as w:
        for f in src:
            w.write(f)
    got = list(open_source(tmp_path / "rec"))
    assert isinstance(open_source(tmp_path / "rec"), FolderSource) and len(got) == 3
    for a, b in zip(src, got):
        assert b.depth.dtype == np.uint16 and np.array_equal(a.depth, b.depth)
        np.testing.assert_allclose(b.K, K_VGA)
        assert np.array_equal(a.rgb, b.rgb) and b.timestamp == pytest.approx(a.timestamp)
    with pytest.raises(errors.SourceError, match="not empty"):
        FolderWriter(tmp_path / "rec")


def test_png_folder_bad_frame_is_an_error_record(tmp_path):
    import cv2
    from equipose.sources import FolderWriter
    with FolderWriter(tmp_path / "rec") as w:
        for f in frames(2, rgb=False):
            w.write(f)
    cv2.imwrite(str(tmp_path / "rec" / "depth" / "000001.png"), np.zeros((480, 640), np.uint8))  # 8-bit frame
    got = list(open_source(tmp_path / "rec"))
    assert isinstance(got[0], Frame) and isinstance(got[1], FrameError) and got[1].error == "DepthDtypeError"
    (tmp_path / "rec" / "intrinsics.json").write_text(json.dumps({"K": [[1, 0], [0, 1]], "width": 1, "height": 1}))
    with pytest.raises(errors.SourceError):
        open_source(tmp_path / "rec")


def test_mcap_round_trip_host_only(tmp_path):
    pytest.importorskip("depthai")
    from equipose.sources import McapReplay, McapWriter
    src = frames(3)
    with McapWriter(tmp_path / "rec.mcap") as w:
        for f in src:
            w.write(f)
    assert (tmp_path / "rec.rgb.mcap").is_file()
    replay = open_source(tmp_path / "rec.mcap")
    assert isinstance(replay, McapReplay) and replay.count == 3
    got = list(replay)
    assert len(got) == 3
    for a, b in zip(src, got):
        assert np.array_equal(a.depth, b.depth) and b.depth.dtype == np.uint16
        np.testing.assert_allclose(b.K, K_VGA, rtol=1e-6)                        # per-frame intrinsics survive
        assert b.image_size == (640, 480) and np.array_equal(a.rgb, b.rgb)
        assert b.timestamp == pytest.approx(a.timestamp, abs=1e-3)
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(errors.SourceError, match="not an .mcap"):
        McapReplay(tmp_path / "junk.mcap")


def _write_pcd(path, xyz, organized=True):
    from pypcd4 import Encoding, PointCloud
    H, W, _ = xyz.shape
    pc = PointCloud.from_xyz_points(xyz.reshape(-1, 3).astype(np.float32))
    if organized:
        pc.metadata.width, pc.metadata.height = W, H
    pc.save(path, encoding=Encoding.BINARY_COMPRESSED)


def test_organized_pcd_becomes_depth_and_intrinsics(tmp_path):
    pytest.importorskip("pypcd4")
    from equipose.sources import PcdSource
    depth, _ = sphere_scene((0.0, 0.0, 0.8), 0.05)
    H, W = depth.shape
    yy, xx = np.mgrid[:H, :W]
    z = depth / 1000.0
    xyz = np.stack([(xx - K_VGA[0, 2]) * z / K_VGA[0, 0], (yy - K_VGA[1, 2]) * z / K_VGA[1, 1], z], -1)
    xyz[:20] = np.nan                                                           # invalid rows
    _write_pcd(tmp_path / "scene.pcd", xyz)
    (f,) = list(PcdSource(tmp_path / "scene.pcd"))
    expect = depth.copy()
    expect[:20] = 0
    assert np.array_equal(f.depth, expect)
    np.testing.assert_allclose(f.K, K_VGA, atol=1e-3)
    _write_pcd(tmp_path / "flat.pcd", xyz[:50, :50], organized=False)
    (bad,) = list(PcdSource(tmp_path / "flat.pcd"))
    assert isinstance(bad, FrameError) and "unorganized" in bad.message


def test_real_pcl_mug_scene(data_root):
    pytest.importorskip("pypcd4")
    from equipose.sources import PcdSource
    (f,) = list(PcdSource(data_root / "kinect_pcl_objects" / "tutorials" / "table_scene_mug_stereo_textured.pcd"))
    assert f.depth.shape == (480, 640) and f.rgb.shape == (480, 640, 3)
    assert 0.5 < np.median(f.depth[f.depth > 0]) / 1000 < 1.5                   # a tabletop ~0.9 m away
    assert 900 < f.K[0, 0] < 1000


def test_record_command_png_and_mcap(tmp_path):
    from equipose.cli import main
    from equipose.samples import sample_path
    assert main(["record", "--source", str(sample_path()), "-o", str(tmp_path / "png")]) == 0
    a = list(open_source(tmp_path / "png"))
    b = list(open_source(sample_path()))
    assert len(a) == 1 and np.array_equal(a[0].depth, b[0].depth)
    pytest.importorskip("depthai")
    assert main(["record", "--source", str(tmp_path / "png"), "-o", str(tmp_path / "r.mcap")]) == 0
    (c,) = list(open_source(tmp_path / "r.mcap"))
    assert np.array_equal(c.depth, b[0].depth)


def test_oak_camera_is_created_without_touching_a_device():
    from equipose.sources import OakCamera
    cam = open_source("oak", size=(640, 400), fps=15)
    assert isinstance(cam, OakCamera) and cam._pipeline is None                 # nothing opened until iteration
    cam.close()
    with pytest.raises(errors.ConfigError):
        OakCamera(size=(0, 400))
