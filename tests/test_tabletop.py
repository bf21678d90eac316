"""Tabletop data (cup / bowl / can at metric scale): sources, up convention, cache layout, ICP templates."""
import numpy as np
import pytest

from equipose.errors import ConfigError
from equipose.train.tabletop import TABLETOP, ensure_tabletop_cache, is_tabletop, tabletop_sources


def test_registry():
    assert set(TABLETOP) == {"cup", "bowl", "can"}
    assert is_tabletop("can") and not is_tabletop("airplane")
    for spec in TABLETOP.values():          # scale covers the largest instance: max radius ≤ 0.5 model units
        assert spec.radius_m[1] / spec.scale <= 0.5 + 1e-9
    with pytest.raises(ConfigError):
        tabletop_sources(".", "airplane", "train")


def test_can_sources_are_upright_and_metric(data_root):
    src = tabletop_sources(data_root, "can", "train")
    meshes = [(name, complete) for name, shape, complete in src if not name.startswith("modelnet/")]
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


def test_tabletop_cache_layout(data_root, tmp_path):
    from equipose.train.data import RenderedPartial
    from equipose.train.render import ensure_cache
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
    from equipose.train.evaluate import _icp_template_clouds
    clouds = _icp_template_clouds(data_root, "cup")
    r = np.linalg.norm(clouds[0], axis=1).max()
    assert abs(r - np.mean(TABLETOP["cup"].radius_m)) < 1e-6
    assert abs(np.linalg.norm(_icp_template_clouds(data_root, "airplane")[0], axis=1).max() - 1.0) < 1e-3
