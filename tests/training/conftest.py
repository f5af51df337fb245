"""Shared fixtures of the training-script tests."""

import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

SHIPPED = ROOT / "isettorch" / "assets" / "demosaic_learned.pt"


@pytest.fixture
def tiny_heldout_sets(tmp_path) -> list[str]:
    """Two held-out folders of two 48 px scenes (training/make_heldout.py): version 5, and green and blue at half."""
    from training import make_heldout

    sets = []
    for k, extra in enumerate(([], ["--channel-gains", "1", "0.5", "0.5"])):
        folder = tmp_path / f"set{k}"
        assert make_heldout.main(["--out", str(folder), "--n", "2", "--size", "48", "--quiet", *extra]) == 0
        sets.append(str(folder))
    return sets


@pytest.fixture
def damaged_shipped(tmp_path) -> Path:
    """A checkpoint of the shipped noise-free network with its output head scaled by 0.3 (a worse network)."""
    state = torch.load(SHIPPED, weights_only=True)
    state["model"] = {k: v * 0.3 if k.startswith("head.") else v for k, v in state["model"].items()}
    path = tmp_path / "worse.pt"
    torch.save(state, path)
    return path
