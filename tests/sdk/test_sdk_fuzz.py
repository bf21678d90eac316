"""Property tests (hypothesis): on arbitrary input, every public entry point either returns a proper pose or raises one
of the package's own errors — nothing else escapes. Longer runs: ``EQUIPOSE_FUZZ_EXAMPLES=2000 pytest -k fuzz``."""
import json
import os

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

from conftest import K_VGA, sphere_scene  # noqa: E402
from equipose import errors  # noqa: E402
from equipose.runtime.result import FrameError, PoseResult  # noqa: E402

FUZZ = settings(max_examples=int(os.environ.get("EQUIPOSE_FUZZ_EXAMPLES", "40")), deadline=None,
                derandomize="EQUIPOSE_FUZZ_EXAMPLES" not in os.environ,                # CI: the same examples each run
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                       HealthCheck.data_too_large])

DTYPES = st.sampled_from([np.uint16, np.float32, np.float64, np.int32, np.int64, np.uint8, np.bool_, np.uint32])
floats = st.floats(allow_nan=True, allow_infinity=True, width=32)


def depth_frames():
    """Small frames of many dtypes: a 0.6–1.2 m slab with holes, or raw random values (NaN/Inf included)."""
    raw = DTYPES.flatmap(lambda dt: hnp.arrays(dt, st.tuples(st.integers(0, 48), st.integers(0, 64)),
                                               elements=floats if np.dtype(dt).kind == "f" else None))
    plausible = st.builds(lambda seed, hole: _slab(seed, hole), st.integers(0, 10 ** 6), st.floats(0.0, 1.0))
    return st.one_of(raw, plausible)


def _slab(seed, hole):
    rng = np.random.default_rng(seed)
    d = rng.integers(600, 1200, size=(48, 64)).astype(np.uint16)
    d[rng.random(d.shape) < hole] = 0
    return d


intrinsics = st.one_of(
    st.just(np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])),
    hnp.arrays(np.float64, st.sampled_from([(3, 3), (9,), (2, 3), (3, 3, 1)]), elements=floats),
    st.lists(st.floats(-1e4, 1e4), min_size=0, max_size=10))
boxes = st.one_of(st.none(), st.tuples(*[st.one_of(st.floats(-100, 200), st.just(float("nan")))] * 4),
                  st.lists(st.integers(-5, 80), max_size=6))


def _check(out):
    """A returned value must be a proper pose (or a per-object FrameError in batch mode)."""
    for r in out if isinstance(out, list) else [out]:
        if isinstance(r, FrameError):
            continue
        assert isinstance(r, PoseResult)
        assert np.all(np.isfinite(r.rotation)) and np.all(np.isfinite(r.translation))
        assert np.allclose(r.rotation @ r.rotation.T, np.eye(3), atol=1e-5) and np.linalg.det(r.rotation) > 0


def _safe(fn, *a, **k):
    try:
        _check(fn(*a, **k))
    except errors.EquiposeError:
        pass


@FUZZ
@given(depth=depth_frames(), K=intrinsics, box=boxes, unit=st.sampled_from(["mm", "m", 0.001, -1, "inch", None]))
def test_fuzz_predict(estimator, depth, K, box, unit):
    _safe(estimator.predict, depth, K, box=box, depth_unit=unit)


@FUZZ
@given(depth=depth_frames(), K=intrinsics, n=st.integers(0, 3), data=st.data())
def test_fuzz_predict_batch_and_auto(estimator, depth, K, n, data):
    regs = [data.draw(boxes) for _ in range(n)]
    _safe(estimator.predict_batch, depth, K, boxes=regs, return_errors=data.draw(st.booleans()))
    _safe(estimator.predict_auto, depth, K)


@FUZZ
@given(points=st.one_of(
    hnp.arrays(st.sampled_from([np.float64, np.float32, np.int64, np.bool_, np.complex64]),
               st.tuples(st.integers(0, 300), st.integers(0, 4)), elements=None),
    hnp.arrays(np.float64, st.tuples(st.integers(60, 400), st.just(3)), elements=st.floats(-3, 3)),
    st.lists(st.lists(st.floats(), max_size=4), max_size=80)))
def test_fuzz_predict_points(estimator, points):
    _safe(estimator.predict_points, points)
    _safe(estimator.predict_points_batch, [points, points])


@FUZZ
@given(depth=depth_frames(), box=boxes, mask_kind=st.sampled_from(["none", "ones", "random", "nan", "wrong"]),
       opts=st.fixed_dictionaries({}, optional={"max_points": st.integers(-2, 5000), "outlier_k": st.integers(-1, 20),
                                                "outlier_std": st.floats(-1, 5), "min_depth": st.floats(-1, 3),
                                                "max_depth": st.floats(-1, 20), "reject_background": st.booleans()}))
def test_fuzz_crop_points(depth, box, mask_kind, opts):
    from equipose.preprocess import crop_points
    shape = np.shape(depth)[:2]
    mask = {"none": None, "ones": np.ones(shape, bool), "random": np.random.default_rng(0).random(shape) > 0.5,
            "nan": np.full(shape, np.nan), "wrong": np.ones((3, 3), bool)}[mask_kind]
    try:
        c = crop_points(depth, K_VGA / 10 + [[0, 0, 0], [0, 0, 0], [0, 0, 0.9]], box=box, mask=mask, **opts)
        assert np.all(np.isfinite(c.points)) and len(c.points) == len(c.pixels)
    except errors.EquiposeError:
        pass


@FUZZ
@given(blob=st.binary(max_size=4000), head=st.sampled_from([b"", b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
                                                            b"TYPE F F F\nCOUNT 1 1 1\nWIDTH 4\nHEIGHT 2\nPOINTS 8\n"
                                                            b"DATA binary\n"]))
def test_fuzz_pcd_reader(tmp_path_factory, blob, head):
    pytest.importorskip("pypcd4")
    from equipose.sources import PcdSource
    path = tmp_path_factory.mktemp("pcd") / "x.pcd"
    path.write_bytes(head + blob)
    for f in PcdSource(path):
        assert isinstance(f, FrameError) or f.depth.dtype == np.uint16


@FUZZ
@given(blob=st.binary(max_size=4000), magic=st.booleans(), footer=st.booleans())
def test_fuzz_mcap_reader(tmp_path_factory, blob, magic, footer):
    from equipose.sources.mcap import McapReplay
    path = tmp_path_factory.mktemp("mcap") / "x.mcap"
    m = b"\x89MCAP0\r\n"
    path.write_bytes((m if magic else b"") + blob + (b"\x02" + bytes(36) + m if footer else b""))
    try:
        src = McapReplay(path)
        if footer and magic and len(blob) < 64:                                 # iterate (needs depthai) on small ones
            pytest.importorskip("depthai")
            list(src)
    except errors.EquiposeError:
        pass


@FUZZ
@given(png=st.binary(max_size=2000), intr=st.one_of(st.binary(max_size=200), st.just(json.dumps(
    {"K": K_VGA.tolist(), "width": 640, "height": 480}).encode())))
def test_fuzz_png_folder(tmp_path_factory, png, intr):
    from equipose.sources import FolderSource
    root = tmp_path_factory.mktemp("png")
    (root / "depth").mkdir()
    (root / "depth" / "000000.png").write_bytes(png)
    (root / "intrinsics.json").write_bytes(intr)
    try:
        for f in FolderSource(root):
            assert isinstance(f, FrameError) or f.depth.dtype == np.uint16
    except errors.EquiposeError:
        pass


def test_fuzz_strategies_reach_the_success_path(estimator):
    """The fuzzers above also exercise successful predictions (a plausible frame gets a pose)."""
    depth, hit = sphere_scene((0.0, 0.0, 0.8), 0.06)
    _check(estimator.predict(depth, K_VGA, mask=hit))
