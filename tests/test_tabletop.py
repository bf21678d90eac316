"""Tabletop data (cup / bowl / can at metric scale): sources, up convention, cache layout, ICP templates."""
import numpy as np
import pytest

from equipose.errors import ConfigError
from equipose.train.data.tabletop import TABLETOP, ensure_tabletop_cache, is_tabletop, tabletop_sources


def test_registry():
    assert set(TABLETOP) == {"cup", "bowl", "can", "mug"}
    assert is_tabletop("can") and not is_tabletop("airplane")
    for spec in TABLETOP.values():          # scale covers the largest instance: max radius ≤ 0.5 model units
        assert spec.radius_m[1] / spec.scale <= 0.5 + 1e-9
    with pytest.raises(ConfigError):
        tabletop_sources(".", "airplane", "train")


def test_can_sources_are_upright_and_metric(data_root):
    src = tabletop_sources(data_root, "can", "train")
    meshes = [(name, complete) for name, shape, complete in src if not name.startswith(("modelnet/", "procedural/"))]
    assert len(meshes) == len(TABLETOP["can"].meshes) + len(TABLETOP["can"].scans)
    for name, p in meshes:
        ext = p.max(0) - p.min(0)
        assert np.argmax(ext) == 2, f"{name} is not upright (extent {ext})"       # cans/bottles are tallest along z
        assert 0.05 < np.linalg.norm(p, axis=1).max() < 0.2, name                # metres, not normalised units
    lo, hi = TABLETOP["can"].radius_m
    radii = [np.linalg.norm(c, axis=1).max() for n, _, c in src if n.startswith("modelnet/")]
    assert lo - 1e-9 <= min(radii) and max(radii) <= hi + 1e-9
    test = tabletop_sources(data_root, "can", "test")
    assert all(n.startswith("modelnet/") for n, _, _ in test)                   # metric meshes never in test
    cyl = [(shape, c) for n, shape, c in src if n.startswith("procedural/cylinder_")]
    assert len(cyl) == TABLETOP["can"].cylinders
    squat = [c for _, c in cyl if np.ptp(c[:, 2]) < np.ptp(c[:, 0])]            # wider than tall: tins
    assert 0.3 * len(cyl) < len(squat) < 0.7 * len(cyl)


def test_mug_sources_have_their_handle_along_x(data_root):
    from equipose.core.handles import fit_handle
    from equipose.train.data.modelnet import category_symmetry
    train, test = tabletop_sources(data_root, "mug", "train"), tabletop_sources(data_root, "mug", "test")
    assert len(train) >= 20 and len(test) >= 5                                  # the handled ModelNet cups + metric mugs
    assert category_symmetry("mug") == "continuous:z"                           # the network's; the handle stage fixes z
    for name, _, c in train + test:
        fit = fit_handle(c)
        assert fit.has_handle, name
        assert abs(np.degrees(fit.azimuth)) < 8.0, (name, np.degrees(fit.azimuth))
        assert np.ptp(c[:, 0]) > np.ptp(c[:, 1]), name                          # the handle makes x the longer side
    cups = {n for n, _, _ in tabletop_sources(data_root, "cup", "test")}
    assert {n for n, _, _ in test} < cups                                       # a strict subset: cups with handles


def test_tabletop_cache_layout(data_root, tmp_path):
    from equipose.train.data.datasets import RenderedPartial
    from equipose.train.data.render_cache import ensure_cache
    path = ensure_tabletop_cache(data_root, "bowl", "test", cache_dir=tmp_path, views=2, limit=3, progress=False,
                                 log=lambda *a: None)
    assert ensure_cache(data_root, "bowl", "test", cache_dir=tmp_path, views=2, limit=3, progress=False) == path
    ds = RenderedPartial(path, 256, train=False)
    assert len(ds) == 6 and ds.scale == TABLETOP["bowl"].scale and ds.category == "bowl"
    z = np.load(path)
    assert np.all((z["translations"][:, 2] > 0.3) & (z["translations"][:, 2] < 1.7))        # metres from the camera
    s = ds.sample(0)
    r = np.linalg.norm(s["canonical"], axis=1).max() * ds.scale                             # back in metres
    assert r <= TABLETOP["bowl"].radius_m[1] * 1.05
    raw = ds.raw(0)
    assert np.abs(np.linalg.norm(raw["points_m"].mean(0) - raw["translation_m"])) < 0.1


def test_icp_templates_are_metric_for_tabletop(data_root):
    from equipose.train.evaluation.evaluate import _icp_template_clouds
    clouds = _icp_template_clouds(data_root, "cup")
    r = np.linalg.norm(clouds[0], axis=1).max()
    assert abs(r - np.mean(TABLETOP["cup"].radius_m)) < 1e-6
    assert abs(np.linalg.norm(_icp_template_clouds(data_root, "airplane")[0], axis=1).max() - 1.0) < 1e-3


def test_procedural_cylinders_are_closed_and_upright():
    from equipose.train.data.shapes import cylinder_mesh, cylinder_proportions, cylinder_surface
    rng = np.random.default_rng(0)
    p = cylinder_surface(0.05, 0.02, 4000, rng)
    rho = np.hypot(p[:, 0], p[:, 1])
    on_side = np.isclose(rho, 0.05)
    on_cap = np.isclose(np.abs(p[:, 2]), 0.01) & (rho <= 0.05 + 1e-12)
    assert np.all(on_side | on_cap) and abs(p[:, 2]).max() <= 0.01 + 1e-12
    # area weighting: side 2πrh vs caps 2πr² → a squat tin has most points on its caps
    assert abs(on_side.mean() - 0.02 / (0.02 + 0.05)) < 0.03
    V, F = cylinder_mesh(0.05, 0.02, segments=32)
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)                                                  # closed (watertight) surface
    tri = V[F]                                                                  # outward normals
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all((n * tri.mean(1)).sum(1) > 0)
    rh = cylinder_proportions(200, seed=1)
    hd = rh[:, 1] / (2 * rh[:, 0])
    assert 0.25 <= hd.min() and hd.max() <= 4.0 and 0.3 < np.mean(hd < 1) < 0.7


def test_can_complete_clouds_add_cylinders(data_root):
    from equipose.train.data.modelnet import load_complete, load_modelnet
    clouds, ids = load_complete(data_root, "can", "test", limit=5)
    bottles, _ = load_modelnet(data_root, "bottle", "test", limit=5)
    assert len(clouds) == 10 and ids[-1] == "cylinder_4" and np.array_equal(clouds[:5], bottles)
    np.testing.assert_allclose(np.linalg.norm(clouds[5:], axis=2).max(1), 1.0, atol=1e-6)
    only, ids = load_complete(data_root, "cylinder", "train", limit=3)                # procedural cylinders only
    assert only.shape == (3, 1024, 3) and ids == ["cylinder_0", "cylinder_1", "cylinder_2"]


def test_calibration_views_rest_upside_down_on_both_halves_of_the_shapes():
    from equipose.train.evaluation.confidence import LYING_EVERY, UPSIDE_DOWN_EVERY, view_rest
    for count in (20, 7, 8, 40):                                               # the test sets' source counts, and more
        rests = [view_rest(v, count, lying=False, upside_down=True) for v in range(200)]
        turned = [v % count for v, r in enumerate(rests) if r == "upside_down"]
        assert abs(len(turned) - 200 / UPSIDE_DOWN_EVERY) <= 200 / count      # about every UPSIDE_DOWN_EVERY-th view
        assert {s % 2 for s in turned} == {0, 1}                               # the fit's shapes and the held-out ones
        assert set(rests) == {"standing", "upside_down"}
    cans = [view_rest(v, 40, lying=True, upside_down=False) for v in range(9)]
    assert cans == ["lying" if v % LYING_EVERY == LYING_EVERY - 1 else "standing" for v in range(9)]   # as before
    assert set(view_rest(v, 20, lying=False, upside_down=False) for v in range(50)) == {"standing"}


def test_the_rest_side_threshold_needs_ten_fixes_per_break():
    from equipose.train.evaluation.rest_side import choose_cap
    down = [{"rest": "upside_down", "own_up": -0.9, "top_cap": 0.2}] * 40 + [{"rest": "upside_down", "own_up": 0.9,
                                                                              "top_cap": 0.2}] * 8
    up = [{"rest": "standing", "own_up": -0.9, "top_cap": 0.09}] * 5 + [{"rest": "standing", "own_up": 0.9,
                                                                         "top_cap": 0.0}] * 400
    choice = choose_cap(down + up)
    assert choice["cap"] == 0.1 and choice["fixes"] == 40 and choice["breaks"] == 0   # 0.05 / 0.08 break 5 of 405
    assert choose_cap(up) is None
    assert choose_cap(down + [{**r, "top_cap": 0.3} for r in up]) is None       # 40 fixes against 5 breaks


def test_the_upright_height_is_the_median_share_of_the_top():
    from equipose.train.evaluation.rest_side import MIN_HEIGHT_ROWS, fit_height
    rows = [{"centre_height": 0.04, "top_height": 0.1}] * 6 + [{"centre_height": 0.05, "top_height": 0.1}] * 5
    assert fit_height(rows) == {"height": 0.4, "height_rows": 11}
    assert fit_height(rows[: MIN_HEIGHT_ROWS - 1]) is None                     # too few results to fit on
