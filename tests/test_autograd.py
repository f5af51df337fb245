"""isettorch._autograd.records_grad: the one "does autograd record this?" test behind the fast paths."""

import torch
from torch import nn

from isettorch._autograd import records_grad
from isettorch.isp.learned import DemosaicNet
from isettorch.sensor.noise import round_half_away


def test_records_grad_tensors_modules_and_grad_mode():
    leaf = torch.ones(3, requires_grad=True)
    plain = torch.ones(3)
    layer = nn.Linear(2, 2)
    assert records_grad(plain, None, 2.0, leaf)
    assert records_grad(plain, layer)  # a module counts through its parameters
    assert not records_grad(plain, None, 2.0)
    assert not records_grad()
    layer.requires_grad_(False)
    assert not records_grad(plain, layer)
    with torch.no_grad():
        assert not records_grad(leaf, nn.Linear(2, 2))
    with torch.inference_mode():
        assert not records_grad(leaf)


def test_fast_paths_follow_grad_mode():
    # a fast path taken under no_grad gives the training path's values (to rounding), and with a gradient the
    # training path is taken: round_half_away's gradient (through round / trunc) is 0
    x = torch.tensor([-2.5, -0.5, 0.5, 1.5, 2.4999], dtype=torch.float64, requires_grad=True)
    y = round_half_away(x)
    assert y.requires_grad and y.tolist() == [-3.0, -1.0, 1.0, 2.0, 2.0]
    with torch.no_grad():
        assert torch.equal(round_half_away(x), y.detach())
    net = DemosaicNet(channels=4, depth=2, base="menon2007").double()
    nn.init.normal_(net.head.weight, std=0.1)
    raw = torch.rand(1, 1, 16, 16, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    trained = net(raw)
    assert trained.requires_grad
    with torch.no_grad():
        torch.testing.assert_close(net(raw), trained.detach(), rtol=0, atol=1e-12)
