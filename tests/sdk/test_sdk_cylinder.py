"""Cylinder stage: a squat tin's axis from its normals; metadata ``shape_prior``."""
import numpy as np
import pytest

from equipose.core.errors import MetadataError
from equipose.runtime.cylinder import cylinder_axis, point_normals
from equipose.runtime.stages.cylinder import CylinderStage
from equipose.testing import posed_state


def closed_cylinder(radius, height, n=1500, seed=0):
    """[P, 3] points on the side and both lids of a z-axis cylinder (centred)."""
    rng = np.random.default_rng(seed)
    side_n = int(n * height / (height + radius))
    a = rng.uniform(0, 2 * np.pi, side_n)
    side = np.c_[radius * np.cos(a), radius * np.sin(a), rng.uniform(-height / 2, height / 2, side_n)]
    lid_n = (n - side_n) // 2
    rr, aa = radius * np.sqrt(rng.uniform(0, 1, 2 * lid_n)), rng.uniform(0, 2 * np.pi, 2 * lid_n)
    lids = np.c_[rr * np.cos(aa), rr * np.sin(aa), np.repeat([height / 2, -height / 2], lid_n)]
    return np.vstack([side, lids])


def view(points, R, toward=(0.0, 0.0, -1.0)):
    """Posed by ``R``, the half facing a camera looking along +z (points with a smaller z than the centre)."""
    P = points @ R.T
    return P[P @ np.asarray(toward) > -0.2 * np.abs(P).max()]


def test_normals_of_a_plane():
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1, 1, (200, 2)), np.zeros(200)]
    assert np.allclose(np.abs(point_normals(P)[:, 2]), 1.0, atol=1e-6)


@pytest.mark.parametrize("tilt", [20.0, 60.0])
def test_squat_tin_lying_axis_is_turned_upright(tilt):
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("x", tilt, degrees=True).as_matrix()
    P = view(closed_cylinder(0.05, 0.04), R)                                    # h/d = 0.4: a squat tin
    truth = R[:, 2]
    wrong = R[:, 0]                                                             # the "lying" answer (longest extent)
    axis, c0, c = cylinder_axis(P, wrong)
    assert c < c0
    assert np.degrees(np.arccos(min(1.0, abs(axis @ truth)))) < 10.0


def test_a_right_axis_is_kept():
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xy", [35.0, -20.0], degrees=True).as_matrix()
    P = view(closed_cylinder(0.03, 0.15), R)                                    # a tall can
    near = Rotation.from_rotvec([0.03, 0.0, 0.0]).as_matrix() @ R[:, 2]         # the network: 1.7° off
    axis, c0, c = cylinder_axis(P, near)
    assert np.allclose(axis, near / np.linalg.norm(near))                       # kept as is (more precise)


def test_cylinder_stage_turns_the_pose():
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("x", 30.0, degrees=True).as_matrix()
    tin = closed_cylinder(0.05, 0.04)
    P = view(tin, R)
    lying = R @ Rotation.from_euler("y", 90.0, degrees=True).as_matrix()        # axis in the tin's plane
    state = posed_state(P, lying, np.zeros(3), canonical=tin)                   # the category shape: a squat tin
    CylinderStage().run(state)
    Rn = state.rotation
    assert np.degrees(np.arccos(min(1.0, abs(Rn[:, 2] @ R[:, 2])))) < 10.0
    assert np.allclose(Rn @ Rn.T, np.eye(3), atol=1e-9) and np.linalg.det(Rn) > 0


def test_shape_prior_metadata():
    from equipose.core.metadata import decode_metadata, encode_metadata
    base = dict(category="can", preset="tiny", model_config={}, num_points=256, num_canonical_points=256, scale=0.25,
                partial=True, symmetry="continuous:z")
    assert decode_metadata(encode_metadata(**base, shape_prior="cylinder"))["shape_prior"] == "cylinder"
    assert decode_metadata(encode_metadata(**base, shape_prior="open_cylinder"))["shape_prior"] == "open_cylinder"
    assert decode_metadata(encode_metadata(**base))["shape_prior"] is None
    with pytest.raises(MetadataError):
        encode_metadata(**base, shape_prior="sphere")
    with pytest.raises(MetadataError):
        decode_metadata(dict(encode_metadata(**base), shape_prior="cone"))


def test_shipped_can_model_uses_the_stage():
    from equipose import PoseEstimator
    assert PoseEstimator("can-tabletop").metadata["shape_prior"] == "cylinder"


def test_a_cylinder_on_a_support_plane_reports_its_axis_upward():
    """The two ends of a can look alike: with a support plane under it the stage keeps +z on the plane's side,
    whichever end the network put up; without a plane it leaves the sign, and so does an open cylinder (a cup)."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xyz", [70, 20, -30], degrees=True).as_matrix()
    P = view(closed_cylinder(0.04, 0.12), R)
    down = R @ Rotation.from_euler("x", 180.0, degrees=True).as_matrix()       # the same can, +z downward
    for unsigned, plane, expected in ((True, R[:, 2], 1.0), (True, None, -1.0), (False, R[:, 2], -1.0)):
        state = posed_state(P, down, np.zeros(3))
        state.support_up = plane
        CylinderStage(unsigned=unsigned).run(state)
        assert state.rotation[:, 2] @ R[:, 2] == pytest.approx(expected, abs=0.02)
        assert np.allclose(state.rotation @ state.rotation.T, np.eye(3), atol=1e-9)


def test_the_side_normals_refine_a_cups_axis():
    """The side of a cup seen from one side, its axis 15° off: the side normals bring a straight side back within 2°
    (either sign kept); a tapered side (its normals 6° off perpendicular) comes closer, with a bias of its own."""
    from scipy.spatial.transform import Rotation
    from equipose.runtime.cylinder import point_normals, refine_side_axis
    rng = np.random.default_rng(4)
    R = Rotation.from_euler("xz", [25.0, 40.0], degrees=True).as_matrix()
    off = Rotation.from_rotvec(np.radians(15.0) * R[:, 0]).as_matrix() @ R[:, 2]
    for taper, bound in ((0.0, 2.0), (0.1, 10.0)):
        h = rng.uniform(0.0, 0.1, 3000)
        r = 0.035 + taper * h                                                   # wider at the top when tapered
        a = rng.uniform(0.0, np.pi, 3000)                                       # the half facing the camera
        P = np.c_[r * np.cos(a), r * np.sin(a), h] @ R.T
        n = point_normals(P, 12)
        assert np.degrees(np.arccos(min(1.0, refine_side_axis(n, off) @ R[:, 2]))) < bound
        assert np.degrees(np.arccos(min(1.0, refine_side_axis(n, -off) @ -R[:, 2]))) < bound


def test_an_up_prior_the_can_contradicts_lays_it_down():
    """Under an up prior a standing can keeps the prior's pose (extra ``rest`` "standing"). A can lying on its side
    while the prior says it stands is turned onto its side: its axis level, within 5° of the truth, its centre
    re-fitted, ``rest`` "lying", ``up_contradicted``, not flagged ``ambiguous`` (the normals decided)."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xyz", [60, 10, 20], degrees=True).as_matrix()    # the can's true pose (camera frame)
    shape = closed_cylinder(0.033, 0.12)
    P = view(shape, R)
    state = posed_state(P, R, np.zeros(3), canonical=shape, up=R[:, 2])
    CylinderStage(unsigned=True).run(state)
    assert np.allclose(state.rotation, R)                                       # the prior's axis is kept
    assert state.extras["rest"] == "standing" and state.extras["up_contradicted"] is False and not state.ambiguous
    assert state.extras["axis_ratio"] > 1.0                                     # no other axis fits better
    stands = R @ Rotation.from_euler("x", 90.0, degrees=True).as_matrix()      # what a wrong "stands" prior gives
    up = stands[:, 2]
    state = posed_state(P, stands, np.array([0.004, -0.003, 0.002]), canonical=shape, up=up)
    CylinderStage(unsigned=True).run(state)
    axis = state.rotation[:, 2]
    assert abs(float(axis @ up)) < 1e-6                                         # level
    assert np.degrees(np.arccos(min(1.0, abs(float(axis @ R[:, 2]))))) < 5.0
    assert np.linalg.norm(state.translation) < 0.004                            # re-centred on the points
    assert state.extras["rest"] == "lying" and state.extras["up_contradicted"] is True and not state.ambiguous
    assert state.extras["axis_ratio"] > 1.0                                     # the lying axis is the better fit


def test_the_table_normal_is_a_candidate_axis():
    """A standing squat tin the network laid down: given the table normal as a candidate, the stage's fit takes it
    (exactly that direction) when it fits the cylinder pattern clearly better; a worse candidate is ignored."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_euler("xyz", [35, -10, 50], degrees=True).as_matrix()
    P = view(closed_cylinder(0.06, 0.05, seed=2), R)                            # squat: wider than tall
    P = P + np.random.default_rng(1).normal(0, 0.0004, P.shape)                 # sensor noise: eigenvectors drift
    lying = R[:, 0]
    axis, c0, c = cylinder_axis(P, lying, candidates=(R[:, 2],))
    assert c < c0 and np.allclose(abs(axis @ R[:, 2]), 1.0, atol=1e-12)
    worse = Rotation.from_rotvec(np.radians(60.0) * R[:, 1]).as_matrix() @ R[:, 2]
    axis2, _, _ = cylinder_axis(P, R[:, 2], candidates=(worse,))
    assert abs(axis2 @ worse) < 0.9                                             # not taken


@pytest.mark.parametrize("strip, off", [(15.0, 10.0), (20.0, 10.0)])
def test_a_lying_can_is_not_stood_up_where_its_outline_says_it_lies(strip, off, monkeypatch):
    """A tall can lying on its side with only a strip of its curved top in view: those normals follow the standing
    pattern (all about parallel to the table normal), so the normals alone take the table normal for the axis. The
    category shape stood on that axis cannot cover the strip's length: the stage keeps the network's lying pose
    (``SWITCH_FIT_RATIO``); without that check it stands the can up."""
    from scipy.spatial.transform import Rotation

    import equipose.runtime.stages.cylinder as stage
    shape = closed_cylinder(0.03, 0.2, n=3000)                                  # a tall can: its outline tells
    R = Rotation.from_euler("y", 90.0, degrees=True).as_matrix()               # lying: its axis along camera x
    up = np.array([0.0, -1.0, 0.0])                                             # the table's normal (camera y down)
    P = shape @ R.T
    radial = (P - np.outer(P @ R[:, 2], R[:, 2])) @ up / 0.03                   # [P] cos of the side normal to up
    pts = P[(np.abs(shape[:, 2]) < 0.0999) & (radial > np.cos(np.radians(strip)))]   # the top strip of the side
    net = Rotation.from_rotvec(np.radians(off) * np.array([0.0, 0.0, 1.0])).as_matrix() @ R   # off° from the truth
    axis, c0, c = cylinder_axis(pts, net[:, 2], candidates=(up,))
    assert c < 0.85 * c0 and abs(axis @ net[:, 2]) < 0.7                        # the normals say: another axis
    for ratio, err in ((stage.SWITCH_FIT_RATIO, off), (np.inf, 90.0)):
        monkeypatch.setattr(stage, "SWITCH_FIT_RATIO", ratio)
        state = posed_state(pts, net, np.zeros(3), canonical=shape)
        state.support_up = up
        CylinderStage(unsigned=True).run(state)
        got = np.degrees(np.arccos(min(1.0, abs(state.rotation[:, 2] @ R[:, 2]))))
        assert got == pytest.approx(err, abs=1.0)
