"""benchmarks/design_noise_bound.py: the Wiener colour estimate against its closed form, and the shipped designs'
captures it reads (issue #36, reporting)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import design_noise_bound as dnb  # noqa: E402  benchmarks/design_noise_bound.py (not part of the package)

from isettorch.design import SHIPPED_DESIGNS, design_path  # noqa: E402


def test_wiener_mse_matches_the_scalar_closed_form():
    # one channel whose mean is the target in each sRGB channel: the Wiener gain is q / (q + s) with q = E[rho^2] and
    # s the noise variance of the mean, and the error s q / (q + s) (Kay 1993, 12.6); s = 0 gives 0
    g = torch.Generator().manual_seed(0)
    rho = torch.rand(24, 1, generator=g, dtype=torch.float64) * 40
    target = rho.expand(24, 3) / 40
    var, frac, window = torch.full((24, 1), 30.0, dtype=torch.float64), torch.tensor([0.5], dtype=torch.float64), 16
    s = 30.0 / (0.5 * 16) / 40**2  # in the target's units
    q = float((target[:, 0] ** 2).mean())
    got = dnb.wiener_mse(rho, var, frac, target, window)
    assert got == pytest.approx(s * q / (q + s), rel=1e-12)
    assert dnb.wiener_mse(rho, torch.zeros_like(var), frac, target, window) == pytest.approx(0.0, abs=1e-20)
    # more light (the same noise, 4x the signal) always lowers the error
    assert dnb.wiener_mse(4 * rho, var, frac, target, window) < got


@pytest.mark.skipif(not all(design_path(n).is_file() for n in SHIPPED_DESIGNS), reason="no shipped designs")
def test_design_capture_counts_photons_of_the_mosaic_channels():
    # Bayer at 10 lux: three channels on 1/4, 1/2, 1/4 of the pixels; ten times the light gives ten times the
    # electrons at the same exposure (1/30 s, the limit, at both levels: the gain differs, not the photons)
    from isettorch.design import load_design

    cam = load_design("bayer_rgb").eval()
    lo, hi = dnb.channel_electrons(cam, 1.0), dnb.channel_electrons(cam, 10.0)
    assert sorted(lo["frac"].tolist()) == [0.25, 0.25, 0.5]
    assert lo["exposure_s"] == pytest.approx(1 / 30) and hi["exposure_s"] == pytest.approx(1 / 30)
    torch.testing.assert_close(hi["rho"], 10 * lo["rho"], rtol=1e-6, atol=0)
    assert lo["rho"].shape == (24, 3) and bool((lo["rho"] > 0).all())
