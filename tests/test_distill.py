"""Partial-view distillation from a complete-shape or a partial-view teacher (train/distill.py): loss semantics,
targets, CLI."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from scipy.spatial.transform import Rotation  # noqa: E402

from equipose.core import icosahedral  # noqa: E402
from equipose.cli import main  # noqa: E402
from equipose.errors import ConfigError  # noqa: E402
from equipose.train.fitting.checkpoint import load_checkpoint  # noqa: E402
from equipose.train.fitting.distill import canonical_clouds, teacher_targets, view_teacher_targets  # noqa: E402
from equipose.train.fitting.losses import distillation_loss, icp_drift, reachable_targets  # noqa: E402


ANCHORS = torch.tensor(icosahedral.ANCHORS, dtype=torch.float32)                   # [60, 3, 3]


def _outputs(R_hyp, t_hyp, shape, scores=None):
    B, A = R_hyp.shape[:2]
    return {"canonical_shape": shape, "hypothesis_rotations": R_hyp, "hypothesis_translations": t_hyp,
            "hypothesis_scores": torch.rand(B, A) if scores is None else scores, "quaternion_norm": torch.ones(B, A)}


def test_loss_is_zero_when_one_hypothesis_matches_the_teacher():
    g = torch.Generator().manual_seed(0)
    S = torch.rand(2, 64, 3, generator=g) - 0.5                                   # teacher shapes [B, M, 3]
    R_t = torch.tensor(Rotation.random(2, random_state=1).as_matrix(), dtype=torch.float32)
    t_t = torch.randn(2, 3, generator=g)
    R_h = torch.tensor(Rotation.random(2 * 60, random_state=2).as_matrix(), dtype=torch.float32).view(2, 60, 3, 3)
    t_h = torch.randn(2, 60, 3, generator=g)
    far, _ = distillation_loss(_outputs(R_h, t_h, S), S, R_t, t_t, ANCHORS)
    near = torch.einsum("aij,bij->ba", ANCHORS, R_t).argmax(1)                    # [B] anchor nearest the target
    other = (near + 1) % 60
    R_h[[0, 1], other], t_h[[0, 1], other] = R_t, t_t                           # a far anchor's hypothesis: no credit
    assert distillation_loss(_outputs(R_h, t_h, S), S, R_t, t_t, ANCHORS)[1]["pose"] > 1e-3
    R_h[[0, 1], near], t_h[[0, 1], near] = R_t, t_t                             # the near anchor's hypothesis hits it
    hit, parts = distillation_loss(_outputs(R_h, t_h, S), S, R_t, t_t, ANCHORS, reach_weight=0.0)
    assert parts["reach"] > 1e-3                                                 # the other 59 are still far
    assert hit.item() < 1e-6 and parts["shape"] < 1e-6 and parts["pose"] < 1e-6
    assert far.item() > 1e-3
    # a wrong canonical shape is penalised even when the pose is right
    wrong, parts = distillation_loss(_outputs(R_h, t_h, S * 1.5), S, R_t, t_t, ANCHORS)
    assert parts["shape"] > 1e-3 and parts["pose"] < 1e-6
    heavy, _ = distillation_loss(_outputs(R_h, t_h, S * 1.5), S, R_t, t_t, ANCHORS, shape_weight=10.0)
    assert heavy.item() - wrong.item() == pytest.approx(9.0 * parts["shape"], rel=1e-4)   # shape_weight scales it
    goals = reachable_targets(ANCHORS, R_t, 40.0)                                # [B, 60, 3, 3]
    ang = np.degrees(np.arccos(np.clip((np.einsum("aij,baij->ba", ANCHORS.numpy(), goals.numpy()) - 1) / 2, -1, 1)))
    assert ang.max() <= 40.0 + 1e-3                                             # within reach of each anchor
    every = distillation_loss(_outputs(goals, t_t[:, None].expand(2, 60, 3), S), S, R_t, t_t, ANCHORS)[0]
    assert every.item() < 1e-5                                                  # all 60 on their reachable goals
    pulled = distillation_loss(_outputs(R_t[:, None].expand(2, 60, 3, 3), t_t[:, None].expand(2, 60, 3), S), S,
                               R_t, t_t, ANCHORS)[0]
    assert pulled.item() > 0.1                                                  # out of reach for far anchors


def test_view_term_measures_the_view_against_the_shape_at_the_teacher_pose():
    g = torch.Generator().manual_seed(3)
    S = torch.rand(2, 64, 3, generator=g) - 0.5                                   # teacher = student shapes [B, M, 3]
    R_t = torch.tensor(Rotation.random(2, random_state=4).as_matrix(), dtype=torch.float32)
    t_t = torch.randn(2, 3, generator=g)
    R_h = torch.tensor(Rotation.random(2 * 60, random_state=5).as_matrix(), dtype=torch.float32).view(2, 60, 3, 3)
    t_h = torch.randn(2, 60, 3, generator=g)
    seen = S[:, :20] @ R_t.transpose(1, 2) + t_t[:, None]                         # [B, 20, 3] part of the posed shape
    out = _outputs(R_h, t_h, S)
    base, parts0 = distillation_loss(out, S, R_t, t_t, ANCHORS)
    on, parts = distillation_loss(out, S, R_t, t_t, ANCHORS, points=seen, view_weight=3.0)
    assert "view" not in parts0 and parts["view"] < 1e-7 and on.item() == pytest.approx(base.item(), abs=1e-6)
    off, parts = distillation_loss(out, S, R_t, t_t, ANCHORS, points=seen + 0.2, view_weight=3.0)
    assert parts["view"] > 1e-3 and off.item() - base.item() == pytest.approx(3.0 * parts["view"], rel=1e-4)
    turned = distillation_loss(out, S, R_t @ R_t, t_t, ANCHORS, points=seen, view_weight=1.0)[1]["view"]
    assert turned > 1e-3                                                          # a different teacher pose misfits
    with pytest.raises(ConfigError, match="input points"):
        distillation_loss(out, S, R_t, t_t, ANCHORS, view_weight=1.0)


def test_drift_is_the_motion_icp_makes_from_the_teacher_pose():
    g = torch.Generator().manual_seed(6)
    S = (torch.rand(1, 1500, 3, generator=g) - 0.5) * torch.tensor([1.0, 0.6, 0.4])   # dense shape [1, M, 3]
    R_t = torch.tensor(Rotation.random(1, random_state=7).as_matrix(), dtype=torch.float32)
    t_t = torch.randn(1, 3, generator=g)
    part = S[:, :200]                                                           # the part a camera sees
    for deg in (0.0, 2.0):
        turn = torch.tensor(Rotation.from_rotvec([0, 0, np.radians(deg)]).as_matrix(), dtype=torch.float32)
        seen = part @ turn.T @ R_t[0].T + t_t                                    # view of the shape turned by `turn`
        drift = icp_drift(seen, R_t, t_t, S, iters=5)                            # [1, 6]
        assert np.degrees(drift[0, :3].norm().item()) == pytest.approx(deg, abs=0.2)
        if deg:                                                                 # it turns the view back, about z
            assert np.degrees(drift[0, 2].item()) == pytest.approx(-deg, abs=0.2)
    # the term: zero at a fixed point, and its gradient reaches the student's shape
    R_h = torch.tensor(Rotation.random(60, random_state=8).as_matrix(), dtype=torch.float32)[None]
    shape = S.clone().requires_grad_(True)
    out = _outputs(R_h, torch.zeros(1, 60, 3), shape)
    exact = part @ R_t[0].T + t_t
    assert distillation_loss(out, S, R_t, t_t, ANCHORS, points=exact, drift_weight=1.0)[1]["drift"] < 1e-8
    loss, parts = distillation_loss(out, S, R_t, t_t, ANCHORS, points=seen, drift_weight=5.0, drift_iters=3)
    assert parts["drift"] > 1e-4
    loss.backward()
    assert shape.grad is not None and shape.grad.abs().sum() > 0
    with pytest.raises(ConfigError, match="input points"):
        distillation_loss(out, S, R_t, t_t, ANCHORS, drift_weight=1.0)


def test_pose_term_ignores_rotations_about_a_symmetry_axis():
    z = torch.linspace(-0.5, 0.5, 20)
    ang = torch.linspace(0, 2 * np.pi, 37)[:-1]
    zz, aa = torch.meshgrid(z, ang, indexing="ij")
    S = torch.stack([0.2 * aa.cos(), 0.2 * aa.sin(), zz], -1).reshape(1, -1, 3)   # cylinder about z [1, 720, 3]
    R_t = torch.eye(3)[None]
    spin = torch.tensor(Rotation.from_euler("z", 50, degrees=True).as_matrix(), dtype=torch.float32)
    tilt = torch.tensor(Rotation.from_euler("x", 50, degrees=True).as_matrix(), dtype=torch.float32)
    for R, small in ((spin, True), (tilt, False)):
        R_h = R.expand(1, 60, 3, 3).clone()
        _, parts = distillation_loss(_outputs(R_h, torch.zeros(1, 60, 3), S), S, R_t, torch.zeros(1, 3), ANCHORS,
                                     symmetric=True)
        assert (parts["pose"] < 1e-3) == small
        _, strict = distillation_loss(_outputs(R_h, torch.zeros(1, 60, 3), S), S, R_t, torch.zeros(1, 3), ANCHORS)
        assert strict["pose"] > 0.5                                               # non-symmetric: the spin counts


def test_selection_term_prefers_the_best_hypothesis():
    S = torch.rand(1, 32, 3) - 0.5
    R_h = ANCHORS[None].clone()                                                  # [1, 60, 3, 3]
    t = torch.zeros(1, 60, 3)
    R_t = R_h[:, 5] @ torch.tensor(Rotation.from_euler("z", 3, degrees=True).as_matrix(), dtype=torch.float32)
    good = torch.full((1, 60), 1.0); good[0, 5] = 0.0
    bad = torch.full((1, 60), 1.0); bad[0, 9] = 0.0
    _, pg = distillation_loss(_outputs(R_h, t, S, good), S, R_t, torch.zeros(1, 3), ANCHORS,
                              select_weight=1.0)
    _, pb = distillation_loss(_outputs(R_h, t, S, bad), S, R_t, torch.zeros(1, 3), ANCHORS,
                              select_weight=1.0)
    assert pg["select"] < pb["select"]


def _teacher_and_views(tmp_path, data_root, category: str, limit: int, **ckpt):
    """A random tiny complete-shape teacher checkpoint, rendered training views (2 each) and complete clouds."""
    from equipose.train.fitting.checkpoint import save_checkpoint
    from equipose.train.data.datasets import make_dataset
    from equipose.train.fitting.distill import complete_clouds
    from equipose.train.network.model import EquiPoseNet
    torch.manual_seed(0)
    teacher = tmp_path / "teacher.pt"
    save_checkpoint(teacher, EquiPoseNet("tiny", partial=False), category=category, scale=2.0, step=0, **ckpt)
    ds = make_dataset(data_root, category, "partial", "train", 256, train=True, limit=limit, cache_dir=tmp_path,
                      render_opts={"views": 2})
    return teacher, ds, complete_clouds(data_root, category, "train", limit=limit)


def test_teacher_targets_follow_the_render_pose(tmp_path, data_root):
    """Every view's target is the teacher's object-frame pose carried by that view's render pose."""
    teacher, ds, clouds = _teacher_and_views(tmp_path, data_root, "airplane", 3)
    tt = teacher_targets(teacher, ds, clouds, refine=2, cache_file=tmp_path / "t.npz", log=lambda *_: None)
    V = len(ds)
    assert tt["rotations"].shape == (V, 3, 3) and tt["translations"].shape == (V, 3)
    assert tt["shapes"].shape[0] == len(clouds) and np.array_equal(tt["instance"], ds.instance)  # one shape per instance
    for v in range(V):
        R = tt["rotations"][v]
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-5)
    # two views of one instance: the relative target rotation is the relative render rotation
    i, j = np.flatnonzero(ds.instance == ds.instance[0])[:2]
    rel_t = tt["rotations"][j] @ tt["rotations"][i].T
    rel_r = ds.R[j] @ ds.R[i].T
    assert np.allclose(rel_t, rel_r, atol=1e-5)
    again = teacher_targets(teacher, ds, clouds, refine=2, cache_file=tmp_path / "t.npz", log=lambda *_: None)
    assert np.array_equal(again["rotations"], tt["rotations"])                   # cached
    from equipose.train.fitting.checkpoint import save_checkpoint
    from equipose.train.network.model import EquiPoseNet
    with pytest.raises(ConfigError, match="complete-shape"):
        student = tmp_path / "student.pt"
        save_checkpoint(student, EquiPoseNet("tiny", partial=True), category="airplane", scale=2.0, step=0)
        teacher_targets(student, ds, clouds, refine=0)


def test_teacher_targets_through_frame_priors(tmp_path, data_root):
    """Frame priors turn each instance's pose and its canonical shape together: the posed shape stays put."""
    teacher, ds, clouds = _teacher_and_views(tmp_path, data_root, "chair", 2)
    with pytest.raises(ConfigError, match="calibration"):
        teacher_targets(teacher, ds, clouds, refine=0, frame_priors="footprint")
    teacher, ds, clouds = _teacher_and_views(tmp_path, data_root, "chair", 2, calibration={
        "rotation": np.eye(3).tolist(), "translation": [0.0, 0.0, 0.0]})
    plain = teacher_targets(teacher, ds, clouds, refine=0, cache_file=tmp_path / "t.npz", log=lambda *_: None)
    turned = teacher_targets(teacher, ds, clouds, refine=0, cache_file=tmp_path / "t.npz", log=lambda *_: None,
                             frame_priors="rest,footprint,mirror:x")                   # a new cache key
    assert not np.allclose(plain["rotations"], turned["rotations"])
    for v in range(len(ds)):
        k = ds.instance[v]
        np.testing.assert_allclose(plain["shapes"][k] @ plain["rotations"][v].T,
                                   turned["shapes"][k] @ turned["rotations"][v].T, atol=1e-4)
    with pytest.raises(ConfigError, match="frame-prior"):
        teacher_targets(teacher, ds, clouds, refine=0, frame_priors="spin")


def test_teacher_targets_through_the_flip_stage(tmp_path, data_root):
    """``flip_model``: a shipped model's flip templates turn instances whose half turn fits them better."""
    teacher, ds, clouds = _teacher_and_views(tmp_path, data_root, "airplane", 2, calibration={
        "rotation": np.eye(3).tolist(), "translation": [0.0, 0.0, 0.0]})
    plain = teacher_targets(teacher, ds, clouds, refine=0, log=lambda *_: None)
    flip = teacher_targets(teacher, ds, clouds, refine=0, flip_model="airplane-complete", log=lambda *_: None)
    for v in range(len(ds)):
        k = ds.instance[v]
        np.testing.assert_allclose(plain["shapes"][k] @ plain["rotations"][v].T,
                                   flip["shapes"][k] @ flip["rotations"][v].T, atol=1e-4)
    with pytest.raises(ConfigError, match="flip_templates"):
        teacher_targets(teacher, ds, clouds, refine=0, flip_model="bottle-complete", log=lambda *_: None)


def test_view_teacher_targets_carry_one_frame_per_instance(tmp_path, data_root):
    """A partial-view teacher: each instance gets one frame (the consensus of its clean views), carried to every view
    by its render pose; a symmetric category needs the teacher's calibration, and the teacher must be partial."""
    from equipose.train.fitting.checkpoint import save_checkpoint
    from equipose.train.network.model import EquiPoseNet
    complete, ds, _ = _teacher_and_views(tmp_path, data_root, "airplane", 3)
    torch.manual_seed(1)
    partial = tmp_path / "partial.pt"
    save_checkpoint(partial, EquiPoseNet("tiny", partial=True), category="airplane", scale=2.0, step=7)
    tt = view_teacher_targets(partial, ds, ds, "none", cache_file=tmp_path / "v.npz", log=lambda *_: None)
    V = len(ds)
    assert tt["rotations"].shape == (V, 3, 3) and tt["translations"].shape == (V, 3)
    assert tt["shapes"].shape[0] == int(ds.instance.max()) + 1 and np.array_equal(tt["instance"], ds.instance)
    for i in np.unique(ds.instance):
        views = np.flatnonzero(ds.instance == i)
        frames = [ds.R[v].T @ tt["rotations"][v] for v in views]             # the object-frame pose of each view
        centres = [ds.R[v].T @ (tt["translations"][v] - ds.t[v] / ds.scale) for v in views]
        for F, c in zip(frames[1:], centres[1:]):
            np.testing.assert_allclose(F, frames[0], atol=1e-5)
            np.testing.assert_allclose(c, centres[0], atol=1e-5)
    again = view_teacher_targets(partial, ds, ds, "none", cache_file=tmp_path / "v.npz", log=lambda *_: None)
    assert np.array_equal(again["rotations"], tt["rotations"])                   # cached
    with pytest.raises(ConfigError, match="calibrate the teacher"):
        view_teacher_targets(partial, ds, ds, "continuous:z", log=lambda *_: None)
    with pytest.raises(ConfigError, match="partial-view model"):
        view_teacher_targets(complete, ds, ds, "none", log=lambda *_: None)


def test_cli_distills_a_partial_model(tmp_path, data_root, capsys):
    teacher_run, run = tmp_path / "teacher", tmp_path / "student"
    common = ["--category", "airplane", "--data-root", str(data_root), "--preset", "tiny", "--batch-size", "2",
              "--train-limit", "3", "--val-size", "6", "--val-every", "2", "--cache-dir", str(tmp_path / "c"),
              "--views", "2", "--steps", "2"]
    assert main(["train", *common, "--mode", "complete", "--out", str(teacher_run)]) == 0
    assert main(["train", *common, "--mode", "complete", "--out", str(run), "--teacher",
                 str(teacher_run / "latest.pt")]) == 2
    assert "use it with --mode partial" in capsys.readouterr().err
    assert main(["train", *common, "--mode", "partial", "--out", str(run), "--teacher",
                 str(teacher_run / "latest.pt"), "--select-weight", "0.1", "--rotate-augment"]) == 0
    ck = load_checkpoint(run / "latest.pt")
    assert ck["partial"] and ck["step"] == 2 and ck["training"]["config"]["teacher"].endswith("latest.pt")
    assert ck["training"]["config"]["rotate_augment"] is True
    assert (run / "teacher.npz").is_file()
    again = tmp_path / "again"                                       # the partial student as a view teacher
    assert main(["train", *common, "--mode", "partial", "--out", str(again), "--teacher",
                 str(run / "latest.pt"), "--init", str(run / "latest.pt")]) == 0
    assert load_checkpoint(again / "latest.pt")["step"] == 2 and (again / "teacher.npz").is_file()


def test_rotate_views_turns_views_and_targets_alike():
    """Every target shape posed by the turned pose lies exactly on the turned view; the centroid stays put."""
    from equipose.train.data.augment import rotate_views
    y = torch.randn(4, 50, 3, dtype=torch.float64)                              # canonical shapes
    R = torch.as_tensor(Rotation.random(4, random_state=1).as_matrix())
    t = torch.randn(4, 3, dtype=torch.float64) + torch.tensor([0.0, 0.0, 5.0])
    x = torch.einsum("bij,bnj->bni", R, y) + t[:, None]                          # views of the shapes
    p, R2, t2 = rotate_views(x, R, t, np.random.default_rng(0))
    torch.testing.assert_close(torch.einsum("bij,bnj->bni", R2, y) + t2[:, None], p)
    torch.testing.assert_close(p.mean(1), x.mean(1))
    turn = torch.einsum("bji,bjk->bik", R, R2)                                   # Rᵀ R' (the same Q per view)
    assert float(torch.linalg.matrix_norm(turn - torch.eye(3, dtype=turn.dtype)).min()) > 1e-3
    with pytest.raises(ConfigError, match="rotate_views"):
        rotate_views(x[0], R, t, np.random.default_rng(0))


def test_distillation_term_weights_are_checked():
    from equipose.train.fitting.config import TrainConfig
    with pytest.raises(ConfigError, match="give --teacher"):
        TrainConfig.from_sources(mode="partial", drift_weight=1.0)
    with pytest.raises(ConfigError, match="drift_iters must be ≥ 1"):
        TrainConfig.from_sources(mode="partial", teacher="t.pt", drift_weight=1.0, drift_iters=0)
    with pytest.raises(ConfigError, match="weights ≥ 0"):
        TrainConfig.from_sources(mode="partial", teacher="t.pt", view_weight=-1.0)
    with pytest.raises(ConfigError, match="give --teacher"):
        TrainConfig.from_sources(mode="partial", cloud_weight=1.0)
    with pytest.raises(ConfigError, match="weights ≥ 0"):
        TrainConfig.from_sources(mode="partial", teacher="t.pt", cloud_weight=-0.5)
    cfg = TrainConfig.from_sources(mode="partial", teacher="t.pt", view_weight=3.0, drift_weight=10.0)
    assert (cfg.view_weight, cfg.drift_weight, cfg.drift_iters) == (3.0, 10.0, 10)


def test_cloud_term_is_the_chamfer_to_the_canonical_cloud():
    g = torch.Generator().manual_seed(8)
    S = torch.rand(2, 64, 3, generator=g) - 0.5                                   # student = teacher shapes [B, M, 3]
    C = torch.cat([S, S[:, :16] + 0.01], dim=1)                                   # clouds [B, 80, 3] on that shape
    R_t = torch.tensor(Rotation.random(2, random_state=9).as_matrix(), dtype=torch.float32)
    t_t = torch.randn(2, 3, generator=g)
    out = _outputs(R_t[:, None].expand(2, 60, 3, 3), t_t[:, None].expand(2, 60, 3), S)
    base, parts0 = distillation_loss(out, S, R_t, t_t, ANCHORS)
    on, parts = distillation_loss(out, S, R_t, t_t, ANCHORS, clouds=C, cloud_weight=2.0)
    assert "cloud" not in parts0 and parts["cloud"] < 1e-3
    far, parts = distillation_loss(out, S, R_t, t_t, ANCHORS, clouds=C * 1.5, cloud_weight=2.0)
    assert parts["cloud"] > 1e-2 and far.item() - base.item() == pytest.approx(2.0 * parts["cloud"], rel=1e-4)
    with pytest.raises(ConfigError, match="canonical clouds"):
        distillation_loss(out, S, R_t, t_t, ANCHORS, cloud_weight=1.0)


def test_canonical_clouds_undo_the_teacher_pose_and_the_render_pose():
    rng = np.random.default_rng(10)
    scale, I, per = 2.0, 3, 2
    clouds = [rng.normal(size=(40, 3)) for _ in range(I)]                          # metres, object frame
    R_i = Rotation.random(I, random_state=11).as_matrix()                          # teacher: canonical → object
    t_i = rng.normal(size=(I, 3)) * 0.1                                            # model units
    inst = np.repeat(np.arange(I), per)                                            # [V]
    R_view = Rotation.random(I * per, random_state=12).as_matrix()                 # render poses [V, 3, 3]
    t_view = rng.normal(size=(I * per, 3))                                         # metres

    class Views:
        R, t = R_view, t_view

    Views.scale = scale
    targets = {"instance": inst, "rotations": R_view @ R_i[inst],
               "translations": np.einsum("vij,vj->vi", R_view, t_i[inst]) + t_view / scale}
    got = canonical_clouds(clouds, targets, Views, points=40)                      # [I, 40, 3]
    for i in range(I):
        want = (clouds[i] / scale - t_i[i]) @ R_i[i]                               # R_iᵀ (c / scale − t_i)
        d = np.linalg.norm(got[i][:, None] - want[None], axis=-1).min(1)           # same points, FPS order
        assert got.shape == (I, 40, 3) and d.max() < 1e-5
