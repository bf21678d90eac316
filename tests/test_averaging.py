"""Weight averaging of one run's snapshots (equipose.train.averaging)."""
import pytest

torch = pytest.importorskip("torch")

from equipose.core.errors import ConfigError  # noqa: E402
from equipose.train.lanes.averaging import average_checkpoints, main  # noqa: E402
from equipose.train.fitting.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint  # noqa: E402
from equipose.train.network.model import EquiPoseNet  # noqa: E402


def _snapshot(path, seed, step, category="chair"):
    torch.manual_seed(seed)
    model = EquiPoseNet("tiny", partial=True)
    return save_checkpoint(path, model, category=category, scale=2.0, step=step,
                           calibration={"rotation": [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]], "translation": [0.0] * 3})


def test_average_is_the_mean_of_the_snapshots_with_the_newest_metadata(tmp_path):
    a, b, c = (_snapshot(tmp_path / f"{s}.pt", s, 100 * s) for s in (1, 2, 3))
    avg = average_checkpoints([b, c, a])
    sa, sb, sc = (load_checkpoint(p)["state_dict"] for p in (a, b, c))
    floats = [k for k, v in sa.items() if v.is_floating_point()]
    assert floats and all(torch.allclose(avg["state_dict"][k], (sa[k] + sb[k] + sc[k]) / 3, atol=1e-6) for k in floats)
    assert any(not torch.equal(sa[k], sb[k]) for k in floats)                  # the snapshots really differ
    assert avg["step"] == 300 and avg["optimizer"] is None and avg["averaged"] == {"count": 3, "steps": [100, 200, 300], "duplicates": 0}
    out = tmp_path / "avg.pt"
    assert main([str(out), str(a), str(b), str(c)]) == 0
    model, ck = model_from_checkpoint(out)                                     # loads and runs like any checkpoint
    y = model(torch.randn(1, model.num_points, 3))
    assert torch.isfinite(y["canonical_shape"]).all() and ck["step"] == 300


def test_snapshots_of_different_runs_are_refused(tmp_path):
    a = _snapshot(tmp_path / "a.pt", 1, 100)
    other = _snapshot(tmp_path / "b.pt", 2, 200, category="sofa")
    with pytest.raises(ConfigError, match="same network"):
        average_checkpoints([a, other])
    with pytest.raises(ConfigError):
        average_checkpoints([])


def test_copies_of_one_step_count_once(tmp_path):
    import shutil
    a, b = _snapshot(tmp_path / "a.pt", 1, 100), _snapshot(tmp_path / "b.pt", 2, 200)
    copies = [shutil.copyfile(b, tmp_path / f"b{i}.pt") for i in range(4)]  # a copy loop that outlived its lane
    avg = average_checkpoints([a, b, *copies])
    sa, sb = (load_checkpoint(p)["state_dict"] for p in (a, b))
    floats = [k for k, v in sa.items() if v.is_floating_point()]
    assert all(torch.allclose(avg["state_dict"][k], (sa[k] + sb[k]) / 2, atol=1e-6) for k in floats)
    assert avg["averaged"] == {"count": 2, "steps": [100, 200], "duplicates": 4}
    other = _snapshot(tmp_path / "c.pt", 3, 200)                                # another run's step 200
    with pytest.raises(ConfigError, match="different weights"):
        average_checkpoints([a, b, other])


def test_snapshot_copier_keeps_one_copy_per_saved_step(tmp_path):
    import os
    from equipose.train.lanes.snapshots import SnapshotCopier
    state, dest = tmp_path / "state", tmp_path / "snaps"
    (state / "m").mkdir(parents=True)
    copier = SnapshotCopier(["m", "absent"], dest, state_dir=state)
    assert copier.poll() == []                                                 # nothing saved yet, no folder needed
    _snapshot(state / "m" / "latest.pt", 1, 100)
    assert [p.name for p in copier.poll()] == ["000000100.pt"]
    assert copier.poll() == []                                                 # unchanged file: no second copy
    os.utime(state / "m" / "latest.pt", ns=(1, 1))                             # touched, same step: still one copy
    assert copier.poll() == []
    _snapshot(state / "m" / "latest.pt", 2, 200)
    made = copier.poll()
    assert [p.name for p in made] == ["000000200.pt"] and load_checkpoint(made[0])["step"] == 200
    assert sorted(p.name for p in (dest / "m").iterdir()) == ["000000100.pt", "000000200.pt"]
    avg = average_checkpoints(sorted((dest / "m").glob("*.pt")))
    assert avg["averaged"]["steps"] == [100, 200]
