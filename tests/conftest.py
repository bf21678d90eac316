import os
import pathlib

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("DEPTHAI_LEVEL", "error")


@pytest.fixture(scope="session")
def data_root():
    """../shared/data beside the repository (or $EQUIPOSE_DATA); tests needing it skip when absent."""
    root = pathlib.Path(os.environ.get("EQUIPOSE_DATA", ROOT.parent / "shared" / "data"))
    if not root.is_dir():
        pytest.skip(f"shared data not found at {root}")
    return root


@pytest.fixture
def rng():
    return np.random.default_rng(0)
