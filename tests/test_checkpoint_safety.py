"""Checkpoint loading runs no code: a pickle that would execute something is refused with a typed error."""
import pathlib
import pickle

import pytest

torch = pytest.importorskip("torch")

from equipose import errors  # noqa: E402
from equipose.train.fitting.checkpoint import load_checkpoint  # noqa: E402

MARK = "equipose-pickle-ran"


class _Payload:
    def __init__(self, target):
        self.target = str(target)

    def __reduce__(self):                                # unpickling would create the marker file
        return pathlib.Path.write_text, (pathlib.Path(self.target), MARK)


def test_malicious_pickle_is_refused(tmp_path):
    target = tmp_path / "pwned.txt"
    path = tmp_path / "evil.pt"
    torch.save({"format": 1, "state_dict": {}, "x": _Payload(target)}, path)
    with pytest.raises(errors.ConfigError, match="cannot be loaded"):
        load_checkpoint(path)
    assert not target.exists()


def test_plain_pickle_and_damaged_files_are_refused(tmp_path):
    (tmp_path / "p.pt").write_bytes(pickle.dumps({"format": 1, "fn": print}))
    (tmp_path / "d.pt").write_bytes(b"PK\x03\x04 damaged zip")
    for name in ("p.pt", "d.pt"):
        with pytest.raises(errors.ConfigError):
            load_checkpoint(tmp_path / name)


def test_shipped_training_state_loads_with_weights_only():
    root = pathlib.Path(__file__).resolve().parents[1] / "train" / "state"
    paths = sorted(root.glob("*/latest.pt"))
    assert paths
    for p in paths:
        ck = load_checkpoint(p)
        assert ck["step"] > 0 and ck["state_dict"]


def test_optimizer_state_follows_the_parameters_device():
    """A resumed Adam's moments load on the CPU; optimizer_to moves them (not the step counters) to the device."""
    import torch
    from equipose.train.fitting.checkpoint import optimizer_to
    w = torch.nn.Parameter(torch.ones(3))
    opt = torch.optim.Adam([w], lr=0.1)
    w.sum().backward()
    opt.step()
    optimizer_to(opt, torch.device("meta"))                                    # any other device than the CPU
    st = opt.state[w]
    assert st["exp_avg"].device.type == "meta" and st["exp_avg_sq"].device.type == "meta"
    assert st["step"].device.type == "cpu"
