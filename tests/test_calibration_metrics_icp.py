"""Calibration (RANSAC consensus), metrics on hand-built cases, ICP-60 on a known rotation."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose.core.geometry import random_rotations, rotation_angle_deg
from equipose.train.evaluation.calibration import (apply_calibration, calibrate_offsets, frame_with_axis,
                                                   ransac_rotation, so3_mean)
from equipose.eval.metrics import rotation_errors, summarize, translation_errors


def _noisy(R, n, deg, rng):
    noise = Rotation.from_rotvec(rng.normal(size=(n, 3)) * np.radians(deg) / np.sqrt(3)).as_matrix()
    return R @ noise


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calibration_recovers_planted_rotation_with_30pct_outliers(seed):
    rng = np.random.default_rng(seed)
    planted = random_rotations(1, seed=seed + 10)[0]
    n_in, n_out = 140, 60                                            # 30 % outliers
    dR = np.concatenate([_noisy(planted, n_in, 1.5, rng),
                         random_rotations(n_out // 2, seed=seed + 20),                     # uniform junk
                         planted @ Rotation.from_euler("z", 180, degrees=True).as_matrix()[None].repeat(n_out // 2, 0)])  # flips
    perm = rng.permutation(len(dR))
    dt = np.concatenate([rng.normal(size=(n_in, 3)) * 0.005 + [0.01, -0.02, 0.03], rng.normal(size=(n_out, 3))])
    cal = calibrate_offsets(dR[perm], dt[perm])
    assert rotation_angle_deg(np.array(cal["rotation"]), planted) < 1.0
    assert np.linalg.norm(np.array(cal["translation"]) - [0.01, -0.02, 0.03]) < 0.005
    assert 0.6 < cal["inlier_fraction"] <= 0.75


def test_naive_mean_fails_where_ransac_succeeds():
    """The test can fail: a plain chordal mean of the same data is pulled off by a 30 % wrong mode."""
    rng = np.random.default_rng(5)
    planted = random_rotations(1, seed=7)[0]
    flip = planted @ Rotation.from_euler("x", 90, degrees=True).as_matrix()
    dR = np.concatenate([_noisy(planted, 70, 1.0, rng), flip[None].repeat(30, 0)])
    assert rotation_angle_deg(so3_mean(dR), planted) > 1.0
    assert rotation_angle_deg(ransac_rotation(dR)[0], planted) < 1.0


def test_symmetric_calibration_recovers_up_axis():
    rng = np.random.default_rng(1)
    planted = random_rotations(1, seed=3)[0]
    spins = Rotation.from_rotvec(np.outer(rng.uniform(0, 2 * np.pi, 100), [0, 0, 1])).as_matrix()
    dR = np.concatenate([spins[:70] @ _noisy(planted, 70, 1.0, rng), random_rotations(30, seed=4)])  # spin about up
    cal = calibrate_offsets(dR, np.zeros((100, 3)), symmetry="continuous:z")
    u = np.array(cal["rotation"])[2]                                  # δRᵀ e_z
    assert np.degrees(np.arccos(np.clip(u @ planted[2], -1, 1))) < 1.0
    # applying it to a prediction R = R_gt · δR gives the right up axis
    R_gt = random_rotations(1, seed=9)[0]
    Rh, _ = apply_calibration(R_gt @ dR[0], np.zeros(3), cal)
    assert rotation_errors(Rh[None], R_gt[None], "continuous:z")[0] < 3.0


def test_apply_calibration_round_trip():
    dR, dt = random_rotations(1, seed=1)[0], np.array([0.1, -0.2, 0.05])
    R_gt, t_gt = random_rotations(1, seed=2)[0], np.array([0.3, 0.1, 1.2])
    Rh, th = apply_calibration(R_gt @ dR, R_gt @ dt + t_gt, {"rotation": dR, "translation": dt})
    assert np.allclose(Rh, R_gt) and np.allclose(th, t_gt)


def test_frame_with_axis_is_rotation():
    for u in (np.array([0, 0, 1.0]), np.array([0.3, -0.5, 0.2])):
        for ax in range(3):
            F = frame_with_axis(u, ax)
            assert np.allclose(F @ F.T, np.eye(3)) and np.isclose(np.linalg.det(F), 1)
            assert np.allclose(F[ax], u / np.linalg.norm(u))


def test_rotation_errors_hand_built():
    I = np.eye(3)
    Rz90 = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    Rx180 = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    Rx30 = Rotation.from_euler("x", 30, degrees=True).as_matrix()
    pred = np.stack([I, Rz90, Rx180, Rx30 @ Rz90])
    gt = np.stack([I, I, I, I])
    e = rotation_errors(pred, gt)
    assert np.allclose(e[:3], [0, 90, 180], atol=1e-6) and e[3] > 30
    s = rotation_errors(pred, gt, "continuous:z")                    # spin about up is free
    assert np.allclose(s, [0, 0, 180, 30], atol=1e-3)
    c = rotation_errors(pred, gt, "continuous:z", unsigned_axis=True)  # cans: upside-down is the same
    assert np.allclose(c, [0, 0, 0, 30], atol=1e-3)


def test_summarize_hand_built():
    r = np.array([1.0, 3.0, 10.0, 170.0])
    t = np.array([0.01, 0.2, 0.01, 0.0])
    row = summarize("x", r, t)
    assert row["rot_mean_deg"] == pytest.approx(46.0) and row["rot_median_deg"] == pytest.approx(6.5)
    assert row["acc_5deg"] == 0.5 and row["acc_5deg_005"] == 0.25 and row["flip_rate"] == 0.25
    assert row["trans_median"] == pytest.approx(0.01)
    assert np.allclose(translation_errors([[3, 4, 0]], [[0, 0, 0]], [10.0]), [0.5])


def _tripod(rng, n):
    """Three orthogonal arms of different lengths: no rotation maps it onto itself."""
    arm = rng.integers(0, 3, n)
    s = rng.uniform(0, 1, n) * np.array([0.5, 0.3, 0.15])[arm]
    p = np.zeros((n, 3))
    p[np.arange(n), arm] = s
    return p + rng.normal(size=(n, 3)) * 0.01


@pytest.mark.parametrize("bidirectional", [False, True])
def test_icp60_recovers_known_rotation(bidirectional):
    from equipose.train.evaluation.icp import icp60
    rng = np.random.default_rng(0)
    tmpl = _tripod(rng, 500)
    for seed in (11, 12):
        R = random_rotations(1, seed=seed)[0]
        t = np.array([0.2, -0.1, 1.5])
        obs = tmpl[rng.permutation(500)[:300]] @ R.T + t + rng.normal(size=(300, 3)) * 0.002   # noisy subset
        Rh, th, res = icp60(obs, tmpl, iters=30, bidirectional=bidirectional)
        assert rotation_angle_deg(Rh, R) < 1.0
        assert np.linalg.norm(th - t) < 0.01


def test_icp60_outputs_follow_the_model_contract():
    """icp60_outputs: shapes of the network's outputs; its best-scored hypothesis is icp60's answer, per batch item."""
    from equipose.train.evaluation.icp import icp60, icp60_outputs
    rng = np.random.default_rng(1)
    tmpl = _tripod(rng, 400)
    obs = np.stack([tmpl[rng.permutation(400)[:256]] @ random_rotations(1, seed=s)[0].T + [0.1, 0, 0.2]
                    for s in (3, 4)])                                             # [2, 256, 3]
    out = icp60_outputs(obs, tmpl, iters=10)
    assert out["hypothesis_rotations"].shape == (2, 60, 3, 3) and out["hypothesis_translations"].shape == (2, 60, 3)
    assert out["hypothesis_scores"].shape == (2, 60) and out["canonical_shape"].shape == (2, 400, 3)
    for b in range(2):
        R, t, res = icp60(obs[b], tmpl, iters=10)
        j = int(np.argmin(out["hypothesis_scores"][b]))
        assert rotation_angle_deg(out["hypothesis_rotations"][b, j].astype(np.float64), R) < 0.05           # float32 outputs
        assert abs(out["hypothesis_scores"][b, j] - res) < 1e-6 * max(1.0, res)


def test_calibrate_model_rotated_inputs_recover_offset():
    """calibrate_model(..., rotations=...) undoes the presented rotation: a perfectly equivariant fake model whose
    frame is offset by δR from the category frame yields δR back (within 1°)."""
    torch = pytest.importorskip("torch")
    from equipose.core.geometry import random_rotations, rotation_angle_deg
    from equipose.train.evaluation.icp import kabsch
    from equipose.train.evaluation.inference import calibrate_model

    rng = np.random.default_rng(3)
    ref = rng.normal(size=(64, 3)) * [0.3, 0.2, 0.1]                       # category-frame reference cloud
    dR = random_rotations(1, seed=11)[0]

    class Fake(torch.nn.Module):
        def forward(self, x):                                              # x [B, N, 3] = ref rotated by R_in
            xs = x.double().numpy()
            R_in, _ = kabsch(np.repeat(ref[None], len(xs), 0), xs)          # [B, 3, 3]
            R = torch.from_numpy(np.einsum("bij,jk->bik", R_in, dR)).float()  # prediction R_in · δR
            B = len(xs)
            return {"hypothesis_rotations": R[:, None].repeat(1, 60, 1, 1), "hypothesis_translations":
                    torch.zeros(B, 60, 3), "hypothesis_scores": torch.zeros(B, 60)}

    canon = np.repeat(ref[None], 12, 0)
    cal = calibrate_model(Fake(), canon, rotations=random_rotations(12, seed=5))
    assert rotation_angle_deg(np.asarray(cal["rotation"]), dR) < 1.0


def test_metrics_for_metadata_keeps_our_row_plain_or_refined():
    from equipose.train.evaluation.evaluate import metrics_for_metadata
    from equipose.eval.metrics import ROW_KEYS
    row = {k: 1.0 for k in ROW_KEYS[1:]}
    for ours in ("equipose", "equipose+icp5"):
        res = {"category": "cup", "mode": "partial", "n": 100, "_info": {"icp_samples": 40},
               "rows": [{"method": ours, **row, "rot_median_deg": 2.5}, {"method": "icp60", **row}]}
        m = metrics_for_metadata(res)
        assert m["method"] == ours and m["rot_median_deg"] == 2.5 and m["icp60"]["rot_median_deg"] == 1.0
        assert m["n"] == 100 and m["icp60_samples"] == 40
