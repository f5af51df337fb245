"""The parts of the speed-error family of learned demosaickers (issue #35 item 3) that need no shipped weights: a
DemosaicNet on top of Menon et al. (2007), and the guard's decimated high-pass."""

from __future__ import annotations

import pytest
import torch
from kornia.filters import gaussian_blur2d

from isettorch.isp import learned
from isettorch.isp.demosaicing import demosaic_menon2007, mosaic


def test_untrained_menon_network_is_menon():
    # the head starts at zero, so the untrained network is its base exactly (the MHC default is covered by the
    # training tests); the base is part of the config a checkpoint stores
    raw = torch.rand(2, 1, 24, 32, generator=torch.Generator().manual_seed(1))
    net = learned.DemosaicNet(channels=4, depth=3, base="menon2007")
    torch.testing.assert_close(net(raw), demosaic_menon2007(raw, "RGGB"), rtol=0, atol=0)
    assert net.config()["base"] == "menon2007"
    assert "base" not in learned.DemosaicNet(channels=4, depth=1).config()  # old checkpoints keep their config
    assert learned.DemosaicNet(**net.config()).base == "menon2007"
    with pytest.raises(ValueError, match="base"):
        learned.DemosaicNet(channels=4, depth=1, base="ahd")


def test_decimated_lowpass_approximates_the_gaussian():
    # On a smooth random field (white noise blurred at 6 px), the 8 x 8-pyramid low-pass matches the exact Gaussian
    # of sigma 16 to a few per cent of the low-pass signal away from the borders: both keep the same band (the box
    # and the bilinear interpolation add about d / sqrt(6) = 3.3 px in quadrature to sigma, +2 % in width).
    g = torch.Generator().manual_seed(0)
    x = gaussian_blur2d(torch.randn(1, 3, 200, 264, generator=g, dtype=torch.float64), (37, 37), (6.0, 6.0))
    exact = learned._lowpass(x, 16.0, None)
    fast = learned._lowpass(x, 16.0, 8)
    inner = (..., slice(48, -48), slice(48, -48))
    rel = float((fast - exact)[inner].norm() / exact[inner].norm())
    assert rel < 0.08, rel  # (sigma 14 or 18 exactly: 0.21, 0.13)
    # a constant stays constant (to rounding), whatever the size (199 x 261 is not a multiple of 8)
    c = torch.full((1, 3, 199, 261), 0.37, dtype=torch.float64)
    torch.testing.assert_close(learned._lowpass(c, 16.0, 8), c, rtol=1e-12, atol=0)


def test_fast_guard_keeps_constants_exact_and_checks_its_options():
    field = torch.tensor([0.9, 0.2, 0.1]).view(1, 3, 1, 1).expand(1, 3, 40, 48).contiguous()
    net = learned.DemosaicNet(channels=4, depth=1, base="menon2007",
                              guard={"highpass_sigma_px": 16.0, "highpass_decimation": 8})
    torch.nn.init.normal_(net.head.weight)  # a network whose correction is far from zero
    with torch.no_grad():
        out = net(mosaic(field, "RGGB"))
    assert float((out - field).abs().max()) <= 1e-6
    for bad in (1, 2.5, True):
        with pytest.raises(ValueError, match="highpass_decimation"):
            learned.guard_residual(mosaic(field), torch.zeros_like(field), highpass_decimation=bad)
    with pytest.raises(ValueError, match="highpass_decimation"):  # no coarser than the blur it approximates
        learned.guard_residual(mosaic(field), torch.zeros_like(field), highpass_sigma_px=4.0, highpass_decimation=8)
