"""Function-preserving widening (equipose.train.widen): the wide network computes what the narrow one did."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from equipose.core.presets import get_preset  # noqa: E402
from equipose.errors import ConfigError  # noqa: E402
from equipose.train import EquiPoseNet  # noqa: E402
from equipose.train.fitting.checkpoint import model_from_checkpoint, save_checkpoint  # noqa: E402
from equipose.train.network.widen import widen_checkpoint, widen_model  # noqa: E402

OUTPUTS = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations", "hypothesis_scores")


def _cloud(seed, b=2, n=256):
    rng = np.random.default_rng(seed)
    x = (rng.normal(size=(b, n, 3)) * [0.25, 0.15, 0.1]).astype(np.float32)
    return torch.tensor(x - x.mean(1, keepdims=True))


def _trained_like(preset, partial, seed=0):
    """A network whose weights are not at their initial values (biases and splits then matter)."""
    torch.manual_seed(seed)
    model = EquiPoseNet(preset, partial=partial)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model.eval()


@pytest.mark.parametrize("narrow,wide,partial", [
    ("edge-q", "edge-qw", True),
    ("edge-q", "edge-qw", False),
    ("tiny", get_preset("tiny").replace(name="tiny-w", channels=(16, 16, 32, 32)), False),
])
def test_widened_network_has_the_same_outputs(narrow, wide, partial):
    model = _trained_like(narrow, partial)
    big = widen_model(model, wide, seed=1).eval()
    assert tuple(big.config.channels) == tuple(get_preset(wide).channels)
    assert sum(p.numel() for p in big.parameters()) > sum(p.numel() for p in model.parameters())
    x = _cloud(3, n=model.config.num_points)
    with torch.no_grad():
        a, b = model(x, return_aux=True), big(x, return_aux=True)
    for k in OUTPUTS:
        np.testing.assert_allclose(b[k].numpy(), a[k].numpy(), atol=2e-5, err_msg=k)


def test_copies_are_split_unevenly_so_training_separates_them():
    big = widen_model(_trained_like("edge-q", True), "edge-qw", seed=0)
    w = big.state_dict()["blocks.1.skip.weight"]                       # [32, 32]: inputs c and c + 16 are copies
    first, second = w[:, :16], w[:, 16:]
    assert not torch.allclose(first, second)                           # different gradients for the two copies
    out = big.state_dict()["blocks.1.inter.bias"]
    torch.testing.assert_close(out[:16], out[16:])                     # outputs: exact copies


def test_checkpoint_round_trip(tmp_path):
    model = _trained_like("edge-q", True)
    save_checkpoint(tmp_path / "narrow.pt", model, category="chair", scale=2.0, step=1234)
    info = widen_checkpoint(tmp_path / "narrow.pt", "edge-qw", tmp_path / "wide.pt")
    assert info["from"] == "edge-q" and info["to"] == "edge-qw" and info["step"] == 1234
    big, ck = model_from_checkpoint(tmp_path / "wide.pt")
    assert ck["step"] == 0 and ck["optimizer"] is None and ck["category"] == "chair"
    x = _cloud(5)
    with torch.no_grad():
        np.testing.assert_allclose(big(x)["canonical_shape"].numpy(), model(x)["canonical_shape"].numpy(), atol=2e-5)


def test_presets_that_differ_in_more_than_width_are_refused():
    with pytest.raises(ConfigError, match="differ in"):
        widen_model(_trained_like("edge-q", True), "edge-a")
    with pytest.raises(ConfigError, match="multiple"):
        widen_model(_trained_like("edge-q", True), get_preset("edge-q").replace(name="odd", channels=(24, 24, 48, 48)))
