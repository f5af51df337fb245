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


@pytest.fixture
def resume_is_exact(tmp_path):
    """``check(args) -> straight_out``: ``train_demosaic.main(args)`` for 4 steps stopped after 2 and resumed gives
    the same weights (to 1e-6) as 4 steps in one go; returns the one-go run's folder."""

    def check(args: list[str]) -> Path:
        from training import train_demosaic

        out, straight = tmp_path / "run", tmp_path / "straight"
        assert train_demosaic.main(args + ["--out", str(out), "--stop-after", "2"]) == 0
        assert torch.load(out / "last.pt", map_location="cpu", weights_only=True)["step"] == 2
        assert train_demosaic.main(args + ["--out", str(out)]) == 0
        assert train_demosaic.main(args + ["--out", str(straight)]) == 0
        a = torch.load(out / "last.pt", map_location="cpu", weights_only=True)
        b = torch.load(straight / "last.pt", map_location="cpu", weights_only=True)
        assert a["step"] == b["step"] == 4
        for k, v in b["model"].items():
            torch.testing.assert_close(a["model"][k], v, rtol=0, atol=1e-6)
        return straight

    return check
