"""Instance-level mode with a box prompt: a pose the camera sees through sends the box's other depth clusters to be
posed (``equipose.runtime.instance_clusters``); on a real YCB-Video frame the cracker box behind a mustard bottle."""
import numpy as np
import pytest

from equipose import PoseEstimator, errors
from equipose.runtime.instance_clusters import (GAP_M, SEE_THROUGH_MAX, choose_cluster, fit_shares,
                                                other_cluster_gates, see_through_share)

K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])


def _cube(n: int = 3000, half: float = 0.05, seed: int = 0) -> np.ndarray:
    """[n, 3] metres: points on the surface of a cube of side 2 · half, centred at the origin."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-half, half, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -half, half)
    return p


def test_see_through_share_tells_a_pose_in_front_of_the_surface_from_one_on_or_behind_it():
    depth = np.full((240, 320), 1.0, np.float32)                                # a wall 1 m away
    cube, R = _cube(), np.eye(3)
    assert see_through_share(R, [0.0, 0.0, 0.8], cube, depth, K) > 0.95       # floating in front: seen through
    assert see_through_share(R, [0.0, 0.0, 1.05], cube, depth, K) == 0.0      # its front face on the wall
    assert see_through_share(R, [0.0, 0.0, 1.3], cube, depth, K) == 0.0       # hidden behind the wall
    holes = np.zeros_like(depth)                                                # no valid depth: no evidence
    assert see_through_share(R, [0.0, 0.0, 0.8], cube, holes, K) == 0.0
    with pytest.raises(errors.InvalidPointsError):
        see_through_share(R, [0.0, 0.0, 0.8], cube, depth[None], K)


def test_gates_crop_beyond_and_before_the_chosen_cluster_within_the_depth_range():
    pts = np.array([[0.0, 0.0, 0.78], [0.0, 0.0, 0.80]])
    beyond, before = other_cluster_gates(pts)
    assert beyond == {"min_depth": pytest.approx(0.80 + GAP_M), "max_depth": 10.0}
    assert before == {"min_depth": 0.1, "max_depth": pytest.approx(0.78 - GAP_M)}
    assert other_cluster_gates(pts, min_depth=0.775) == [beyond]               # nothing in front left to crop
    assert other_cluster_gates(pts, max_depth=0.805) == [before]


def test_choose_cluster_keeps_the_box_evidence_pose_unless_it_is_seen_through():
    assert choose_cluster([0.1, 0.0]) == 0                                      # a good pose stays
    assert choose_cluster([0.8, 0.5, 0.02]) == 2                                # the least seen-through wins
    assert choose_cluster([0.8, SEE_THROUGH_MAX + 0.1]) == 0                    # no better candidate: stays
    assert choose_cluster([0.9]) == 0


def test_fit_shares_count_each_crop_against_its_own_pose():
    cube = _cube()
    R = np.stack([np.eye(3)] * 2)
    t = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    crops = [cube[:200] + t[0], np.vstack([cube[:100] + t[1], cube[:100] + [0.0, 0.0, 3.0]])]
    assert fit_shares(R, t, cube, crops) == pytest.approx([1.0, 0.5])
    with pytest.raises(errors.InvalidPointsError):
        fit_shares(R, t, cube, crops[:1])


@pytest.fixture(scope="module")
def demo_frame(data_root):
    import cv2
    d = data_root / "ycb_posecnn"
    depth = cv2.imread(str(d / "demo_images" / "000001-depth.png"), cv2.IMREAD_UNCHANGED)   # uint16, 1e-4 m
    K_c = np.array([[1066.778, 0.0, 312.9869], [0.0, 1067.487, 241.3109], [0.0, 0.0, 1.0]])
    return depth, K_c, d / "models"


@pytest.mark.parametrize("model, box, choice", [
    ("003_cracker_box", (292, 123, 190, 217), "fit"),        # behind the mustard bottle, which the box centres on
    ("006_mustard_bottle", (318, 200, 92, 250), "box"),      # in front of the cracker box: kept as chosen
])
def test_real_frame_the_object_behind_the_one_in_front(demo_frame, model, box, choice):
    depth, K_c, models = demo_frame
    pts = np.loadtxt(models / model / "points.xyz")[:, :3]
    est = PoseEstimator("can-tabletop", threads=1, model_points=pts)
    r = est.predict(depth, K_c, box=box, depth_unit=1e-4)
    tried = r.extras["clusters_tried"]
    assert r.extras["cluster_choice"] == choice
    kept = tried[0] if choice == "box" else min(tried, key=lambda c: c["see_through"])
    assert kept["see_through"] <= SEE_THROUGH_MAX and kept["fit"] > 0.6
    if choice == "fit":                                                         # the bottle's cluster, then its face
        assert tried[0]["see_through"] > SEE_THROUGH_MAX and tried[0]["depth_m"] < kept["depth_m"] - 0.1
    assert r.extras["model_fit"] == kept["fit"] and r.extras["see_through"] == kept["see_through"]
    assert r.timings["model_check"] > 0 and r.timings["total"] > r.timings["model_check"]


def test_every_instance_result_reports_its_fit_and_see_through(demo_frame):
    depth, K_c, models = demo_frame
    pts = np.loadtxt(models / "035_power_drill" / "points.xyz")[:, :3]
    est = PoseEstimator("can-tabletop", threads=1, model_points=pts)
    box = (45, 250, 235, 115)
    r = est.predict(depth, K_c, box=box, depth_unit=1e-4)                      # one cluster: nothing re-cropped
    assert "clusters_tried" not in r.extras and r.extras["model_fit"] > 0.8 and r.extras["see_through"] < 0.3
    mask = np.zeros(depth.shape, bool)
    mask[250:365, 45:280] = True
    rm = est.predict(depth, K_c, mask=mask, depth_unit=1e-4)                   # a mask crop is checked too
    assert 0.0 <= rm.extras["model_fit"] <= 1.0 and 0.0 <= rm.extras["see_through"] <= 1.0


def test_real_frame_a_crop_holding_a_neighbour_is_posed_by_the_trimmed_search(data_root):
    import cv2
    d = data_root / "ycb_posecnn"
    depth = cv2.imread(str(d / "demo_images" / "000003-depth.png"), cv2.IMREAD_UNCHANGED)   # the can before the tin
    K_c = np.array([[1066.778, 0.0, 312.9869], [0.0, 1067.487, 241.3109], [0.0, 0.0, 1.0]])
    pts = np.loadtxt(d / "models" / "005_tomato_soup_can" / "points.xyz")[:, :3]
    est = PoseEstimator("can-tabletop", threads=1, model_points=pts)
    r = est.predict(depth, K_c, box=(178, 298, 101, 158), depth_unit=1e-4)
    assert r.extras["trimmed"] and r.extras["model_fit"] > 0.85              # untrimmed: 0.45 of its crop


def test_re_crops_stand_on_the_first_crops_support_plane(demo_frame):
    """Every re-crop of the box is cut with the support plane found under the first crop and posed with it (the
    confidence reads the pose against it), not with a plane refitted to the whole frame."""
    depth, K_c, models = demo_frame
    pts = np.loadtxt(models / "003_cracker_box" / "points.xyz")[:, :3]
    est = PoseEstimator("can-tabletop", threads=1, model_points=pts)
    calls, infers = [], []
    crop, infer = est.crop, est._infer
    est.crop = lambda *a, **kw: calls.append(kw) or crop(*a, **kw)
    est._infer = lambda *a, **kw: infers.append(kw.get("support_planes")) or infer(*a, **kw)
    r = est.predict(depth, K_c, box=(292, 123, 190, 217), depth_unit=1e-4)
    assert r.extras["cluster_choice"] == "fit" and len(calls) >= len(r.extras["clusters_tried"]) >= 2
    first = calls[0]["support_plane"]
    for kw in calls[1:]:
        assert np.array_equal(kw["support_plane"][0], first[0]) and kw["support_plane"][1] == first[1]
        assert "min_depth" in kw or "max_depth" in kw
    assert all(s is not None and len(s) == 1 for s in infers[1:])               # each re-crop posed on its plane
