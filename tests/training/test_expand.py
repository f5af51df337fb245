"""training/expand.py: collapsible linear expansion; the same function at the start, a plain network at the end."""

import sys
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from isettorch.isp.learned import DemosaicNet  # noqa: E402
from training import train_demosaic  # noqa: E402
from training.expand import collapsed_state, expand_convolutions, is_expanded  # noqa: E402

SMOKE = ROOT / "configs" / "train" / "demosaic_smoke.yaml"


def _net(seed=0):
    torch.manual_seed(seed)
    net = DemosaicNet(channels=8, depth=3).double()
    with torch.no_grad():  # a trained-looking head (a fresh one is zero: the output would be MHC whatever happened)
        net.head.weight.normal_(0, 0.05)
    return net


def test_expansion_starts_at_the_same_function_and_collapses_to_the_plain_network():
    raw = torch.rand(2, 1, 16, 16, dtype=torch.float64)
    net = _net()
    with torch.no_grad():
        ref = net(raw)
    expand_convolutions(net, 32)
    assert is_expanded(net)
    w1 = net.body[2].parametrizations.weight.original0
    assert tuple(w1.shape) == (32, 8, 3, 3)
    with torch.no_grad():
        torch.testing.assert_close(net(raw), ref, rtol=0, atol=1e-12)
    # a few optimiser steps on the factors move the function; the collapsed weights are a plain network computing it
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(3):
        opt.zero_grad()
        F.mse_loss(net(raw), torch.rand_like(ref)).backward()
        opt.step()
    plain = DemosaicNet(channels=8, depth=3).double()
    plain.load_state_dict(collapsed_state(net))
    with torch.no_grad():
        moved = net(raw)
        assert float((moved - ref).abs().max()) > 1e-3
        torch.testing.assert_close(plain(raw), moved, rtol=0, atol=1e-12)
    # the collapsed weight is the product of the factors, plus the identity on the body's square convolutions
    p = net.body[2].parametrizations.weight
    want = torch.einsum("om,mikl->oikl", p.original1, p.original0)
    want[torch.arange(8), torch.arange(8), 1, 1] += 1
    torch.testing.assert_close(collapsed_state(net)["body.2.weight"], want.detach(), rtol=0, atol=1e-12)
    p0 = net.body[0].parametrizations.weight  # the first convolution (16 input planes -> 8): no identity
    torch.testing.assert_close(collapsed_state(net)["body.0.weight"],
                               torch.einsum("om,mikl->oikl", p0.original1, p0.original0).detach(), rtol=0, atol=1e-12)


def test_expand_errors_name_the_argument():
    with pytest.raises(ValueError, match="expand"):
        expand_convolutions(_net(), 0)
    with pytest.raises(ValueError, match="expand: expected at least"):
        expand_convolutions(_net(), 4)


def test_expanded_training_resumes_exactly_and_saves_a_plain_checkpoint(tmp_path):
    out = tmp_path / "run"
    args = ["--config", str(SMOKE), "--out", str(out), "--no-progress", "--threads", "1", "--set", "expand=16"]
    assert train_demosaic.main(args + ["--steps", "4", "--stop-after", "2"]) == 0
    assert train_demosaic.main(args + ["--steps", "4"]) == 0
    resumed = torch.load(out / "last.pt", map_location="cpu", weights_only=True)
    straight = tmp_path / "straight"
    assert train_demosaic.main(["--config", str(SMOKE), "--out", str(straight), "--quiet", "--threads", "1",
                                "--steps", "4", "--set", "expand=16"]) == 0
    ref = torch.load(straight / "last.pt", map_location="cpu", weights_only=True)
    plain = DemosaicNet(**resumed["net_config"])
    plain.load_state_dict(resumed["model"])  # the library's format: no factors
    assert set(resumed["model"]) == set(plain.state_dict())
    for k, v in ref["model"].items():
        torch.testing.assert_close(resumed["model"][k], v, rtol=0, atol=1e-6)
    # a plain run from the same seed takes other steps (the factors' optimisation differs)
    other = tmp_path / "plain"
    assert train_demosaic.main(["--config", str(SMOKE), "--out", str(other), "--quiet", "--threads", "1",
                                "--steps", "4"]) == 0
    o = torch.load(other / "last.pt", map_location="cpu", weights_only=True)
    assert float((o["model"]["body.0.weight"] - ref["model"]["body.0.weight"]).abs().max()) > 1e-6
