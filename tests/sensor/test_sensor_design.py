"""Sensor designs: the filter bank (manufacturable: transmittance in [0, 1], a slope bound), the learnable mosaic
(relaxed in training, hard in eval and export) and their place in the library's Sensor (fixed designs reproduce
the plain sensor exactly)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from isettorch import spectral
from isettorch.optics.optical_image import OpticalImage
from isettorch.sensor import CFA, Sensor
from isettorch.sensor.design import FIXED_DESIGNS, KODAK_CFA2, design_sensor, fixed_design, learned_design
from isettorch.sensor.filter_bank import MAX_SLOPE_PER_NM, FilterBank, max_slope_per_nm
from isettorch.sensor.filters import filter_set
from isettorch.sensor.mosaic import LearnedMosaic, temperature_schedule

WL = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
FINE = torch.arange(400.0, 700.01, 0.25, dtype=torch.float64)


def _extreme_bank(band_width_nm: float = 50.0, max_log_odds: float = 3.0) -> FilterBank:
    """Learned filters pushed to the parameterisation's limits: band amplitudes +-A alternating (the steepest
    transmittance it can make), all +A (brightest), all -A (darkest); offsets 0, +A, -A."""
    bank = FilterBank(["learned"] * 3, band_width_nm=band_width_nm, max_log_odds=max_log_odds)
    j = bank.band_centres_nm.numel()
    alt = torch.tensor([(-1.0) ** i for i in range(j)], dtype=torch.float64)
    with torch.no_grad():
        bank.raw_amplitudes.copy_(torch.stack([alt, torch.ones(j), -torch.ones(j)]) * 40)  # tanh(40) = 1
        bank.raw_offsets.copy_(torch.tensor([0.0, 40.0, -40.0]))
    return bank


def test_learned_transmittance_lies_in_0_1_at_every_wavelength():
    bank = _extreme_bank()
    t = bank.learned_transmittance(FINE)
    # sigmoid(+-2A) with A = 3: the brightest and darkest filters the construction allows
    assert float(t.max()) == pytest.approx(1 / (1 + math.exp(-6)), abs=1e-12)
    assert float(t.min()) == pytest.approx(1 / (1 + math.exp(6)), abs=1e-12)
    assert bool(((t > 0) & (t < 1)).all())
    g = torch.Generator().manual_seed(0)
    for _ in range(5):  # random parameters of any size
        with torch.no_grad():
            bank.raw_amplitudes.copy_(torch.randn(bank.raw_amplitudes.shape, generator=g, dtype=torch.float64) * 30)
            bank.raw_offsets.copy_(torch.randn(3, generator=g, dtype=torch.float64) * 30)
        f = bank.filters
        assert bool(((f >= 0) & (f <= 1)).all())


def test_slope_bound_holds_and_is_attained():
    """|dT/dl| <= pi A / (4 w) (filter_bank module docstring), attained midway between two band centres by
    alternating amplitudes; the default bound is under MAX_SLOPE_PER_NM."""
    bank = _extreme_bank()
    bound = max_slope_per_nm(3.0, 50.0)
    assert bound == pytest.approx(math.pi * 3 / 200) and bound < MAX_SLOPE_PER_NM
    t = bank.learned_transmittance(FINE)
    slope = (t[:, 1:] - t[:, :-1]).abs().max() / 0.25
    assert float(slope) <= bound + 1e-12
    assert float(slope) == pytest.approx(bound, rel=1e-3)  # the finite difference over 0.25 nm at the peak slope
    # the library's own filters on their native grid: also within the bound (ISETCam rgb: 0.0099 / nm)
    _, rgb, _ = filter_set("isetcam_rgb", WL, dtype=torch.float64)
    assert float(((rgb[:, 1:] - rgb[:, :-1]) / 10).abs().max()) < MAX_SLOPE_PER_NM
    # narrower bands or larger log-odds would break the bound: refused when the bank is built (a spec with
    # band_width_nm 10 trained to the end and failed only at save_design)
    for kwargs in ({"band_width_nm": 25.0}, {"band_width_nm": 10.0}, {"max_log_odds": 8.0}):
        with pytest.raises(ValueError, match=r"band_width_nm, max_log_odds: the learned filters' slope bound"):
            _extreme_bank(**kwargs)
    assert max_slope_per_nm(3.0, 25.0) > MAX_SLOPE_PER_NM
    assert FilterBank(["R", "W"], band_width_nm=10.0).filters.shape[0] == 2  # fixed filters only: no bound to keep


def test_every_design_is_manufacturable():
    """The check the design files carry: [0, 1], slope <= MAX_SLOPE_PER_NM on the native grid, hard in eval."""
    designs = [fixed_design(n) for n in FIXED_DESIGNS] + [learned_design(seed=s) for s in range(3)]
    for bank, mosaic in designs:
        f = bank.filters
        assert bool(((f >= 0) & (f <= 1)).all())
        slope = ((f[:, 1:] - f[:, :-1]) / (WL[1:] - WL[:-1])).abs().max()
        assert float(slope) <= MAX_SLOPE_PER_NM
        w = mosaic.eval().weights(8, 8)
        assert bool(((w == 0) | (w == 1)).all()) and bool((w.sum(0) == 1).all())


def test_fixed_filters_are_the_library_filters():
    bank = FilterBank(["R", "G", "B", "C", "Y", "M", "W"], learnable=False)
    _, rgb, _ = filter_set("isetcam_rgb", WL, dtype=torch.float64)
    r, g, b = rgb
    expected = torch.stack([r, g, b, g + b, r + g, r + b, torch.ones_like(r)])  # C = G + B, Y = R + G, M = R + B
    torch.testing.assert_close(bank.filters, expected, rtol=0, atol=1e-15)
    assert not bank.learnable and bank.channel_names == ["R", "G", "B", "C", "Y", "M", "W"]


def test_relaxed_mosaic_is_a_softmax_mixture_and_hard_in_eval():
    g = torch.Generator().manual_seed(1)
    m = LearnedMosaic(["A", "B", "C"], (2, 2), init_scale=1.0, seed=4)
    rates = torch.rand(2, 3, 4, 6, generator=g, dtype=torch.float64)
    m.temperature = 0.5
    soft = torch.softmax(m.logits.detach() / 0.5, dim=0)  # [K, 2, 2]
    expected = (rates * soft.repeat(1, 2, 3)[None]).sum(1, keepdim=True)
    torch.testing.assert_close(m.train().mosaic(rates), expected)
    hard = m.eval().mosaic(rates)
    idx = m.logits.detach().argmax(0)
    manual = torch.stack([rates[:, idx[i % 2, j % 2], i, j] for i in range(4) for j in range(6)], -1)
    torch.testing.assert_close(hard, manual.reshape(2, 1, 4, 6), rtol=0, atol=0)
    # the exported design is that same pattern as a plain CFA
    cfa = m.hard_cfa()
    assert type(cfa) is CFA and torch.equal(cfa.mosaic(rates), hard)
    # a cold softmax is the hard mosaic
    m.train().temperature = 1e-4
    torch.testing.assert_close(m.mosaic(rates), hard, rtol=1e-12, atol=1e-12)


def test_straight_through_reads_the_hard_mosaic_with_the_softmax_gradient():
    m = LearnedMosaic(["A", "B", "C"], (2, 2), init_scale=1.0, seed=4, relax="straight_through")
    rates = torch.rand(1, 3, 2, 2, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    out = m.train().mosaic(rates)
    assert torch.equal(out, m.hard_cfa().mosaic(rates))
    out.sum().backward()
    ref = m.logits.detach().clone().requires_grad_(True)
    (rates[0] * torch.softmax(ref / m.temperature, 0)).sum().backward()
    torch.testing.assert_close(m.logits.grad, ref.grad)


def test_temperature_schedule():
    assert temperature_schedule(0, 10, 2.0, 0.02) == 2.0
    assert temperature_schedule(5, 10, 2.0, 0.02) == pytest.approx(0.2)  # geometric mean
    assert temperature_schedule(10, 10, 2.0, 0.02) == pytest.approx(0.02)
    with pytest.raises(ValueError, match="start, end"):
        temperature_schedule(0, 10, 0.0, 0.1)


def test_fixed_designs_layouts():
    bank, m = fixed_design("rgbw")
    assert m.shape == (4, 4) and m.fraction() == {"R": 0.125, "G": 0.25, "B": 0.125, "W": 0.5}
    assert "/".join("".join(r) for r in m.cell) == KODAK_CFA2
    # W on a checkerboard
    assert all((m.cell[i][j] == "W") == ((i + j) % 2 == 0) for i in range(4) for j in range(4))
    assert fixed_design("bayer_rgb")[1].hard_cfa().is_bayer
    assert fixed_design("ycmy")[1].cell == [["Y", "C"], ["M", "Y"]]
    # a fixed mosaic is never relaxed, even in training mode
    assert not m.train().relaxed and bool(((m.weights(4, 4) == 0) | (m.weights(4, 4) == 1)).all())


def _uniform_oi(rows: int, cols: int, spd_photons: torch.Tensor) -> OpticalImage:
    photons = spd_photons.reshape(1, -1, 1, 1).expand(1, -1, rows, cols).contiguous()
    return OpticalImage(photons, WL, sample_spacing_m=2.8e-6)


@pytest.mark.parametrize("name,cell", [("bayer_rgb", "GBRG"), ("ycmy", "YCMY"), ("rgbw", KODAK_CFA2)])
def test_fixed_design_sensor_equals_the_plain_sensor(name, cell):
    """One simulator: a fixed design in the design modules captures exactly what the library's Sensor with that
    CFA and filters does, with noise (same seed) and without."""
    g = torch.Generator().manual_seed(0)
    oi = OpticalImage(torch.rand(1, 31, 8, 8, generator=g, dtype=torch.float64) * 3e15, WL, sample_spacing_m=2.8e-6)
    kw = dict(rows=8, cols=8, pixel_size_m=2.8e-6, read_noise_v=1e-3, dark_current_e_per_s=10.0, adc_bits=10,
              dsnu_sigma_v=1e-3, auto_exposure="luminance")
    bank, mosaic = fixed_design(name)
    designed = design_sensor(bank, mosaic, **kw)
    plain = Sensor(cfa=cell, **kw)  # the library's default filter per letter (R, G, B; C, Y, M; W)
    assert plain.cfa.channel_names == designed.cfa.channel_names
    a = designed(oi, generator=torch.Generator().manual_seed(3))
    b = plain(oi, generator=torch.Generator().manual_seed(3))
    torch.testing.assert_close(a.exposure_s, b.exposure_s, rtol=0, atol=0)
    torch.testing.assert_close(a.data, b.data, rtol=0, atol=0)
    torch.testing.assert_close(a.noise_free, b.noise_free, rtol=1e-15, atol=0)


def test_clear_pixel_photon_advantage():
    """Under D65 a W pixel collects sum(E) / sum(E T_G) times the photo-electrons of a G pixel (the trade of light
    for colour), computed here with NumPy on the filter tables."""
    d65 = spectral.energy_to_photons(spectral.illuminant("D65", WL, dtype=torch.float64), WL, dim=0)
    bank, mosaic = fixed_design("rgbw")
    sensor = design_sensor(bank, mosaic, rows=4, cols=4, pixel_size_m=2.8e-6)
    rate = sensor.electron_rate(_uniform_oi(4, 4, d65 * 1e3))[0, 0]
    idx = mosaic.index_map
    w_rate = float(rate[idx == 3].mean())
    e = d65.numpy()
    _, rgb, _ = filter_set("isetcam_rgb", WL, dtype=torch.float64)
    for c in range(3):
        expected = e.sum() / (e * rgb[c].numpy()).sum()
        assert w_rate / float(rate[idx == c].mean()) == pytest.approx(expected, rel=1e-12)
    assert 6 < w_rate / float(rate[idx == 1].mean()) < 20  # ISETCam's filters peak near 0.35: W collects ~11x G
    assert np.isfinite(w_rate)


def test_peak_scaled_fixed_filters():
    """fixed_scale='peak': each library set divided by its maximum (ratios kept); a clear pixel then collects
    sum(E) / sum(E T_G) = 3.8x the D65 photons of a green one (the "about three times" of a real RGBW sensor)."""
    bank = FilterBank(["R", "G", "B", "C", "Y", "M", "W"], learnable=False, fixed_scale="peak")
    _, rgb, _ = filter_set("isetcam_rgb", WL, dtype=torch.float64)
    _, cym, _ = filter_set("isetcam_cmy", WL, dtype=torch.float64)
    expected = torch.cat([rgb / rgb.max(), cym / cym.max(), torch.ones(1, 31, dtype=torch.float64)])
    torch.testing.assert_close(bank.filters, expected, rtol=0, atol=1e-15)
    assert float(bank.filters[:6].amax()) == 1.0 and float(bank.filters[0].max()) == 1.0  # R peaks at 1
    assert float(bank.filters[1].max()) == pytest.approx(0.347794 / 0.386465)  # G keeps its ratio to R
    e = spectral.energy_to_photons(spectral.illuminant("D65", WL, dtype=torch.float64), WL, dim=0).numpy()
    ratio = e.sum() / (e * bank.filters[1].numpy()).sum()
    assert 3.0 < ratio < 4.5
    with pytest.raises(ValueError, match="fixed_scale"):
        FilterBank(["R"], fixed_scale="unit")


def test_design_parameters_belong_to_the_sensor():
    bank, mosaic = learned_design(("learned", "learned", "W"), (4, 4))
    s = design_sensor(bank, mosaic, rows=8, cols=8)
    names = {n for n, p in s.named_parameters() if p.requires_grad}
    assert names == {"cfa.logits", "spectral_qe.raw_amplitudes", "spectral_qe.raw_offsets"}
    assert s.cfa is mosaic and s.spectral_qe is bank
    sd = s.state_dict()
    assert "cfa.logits" in sd and "spectral_qe.fixed_filters" in sd
    bank.freeze()
    assert not bank.learnable and not bank.raw_amplitudes.requires_grad
    torch.testing.assert_close(bank(WL), bank.filters)  # frozen: the cached path holds the learned rows


def test_bad_input_raises():
    with pytest.raises(ValueError, match="filters: unknown filter 'Q'"):
        FilterBank(["learned", "Q"])
    with pytest.raises(ValueError, match="pattern"):
        LearnedMosaic(["A", "B"], pattern=[[0, 2]])
    with pytest.raises(ValueError, match="temperature"):
        LearnedMosaic(["A", "B"]).temperature = 0.0
    with pytest.raises(ValueError, match="relax"):
        LearnedMosaic(["A", "B"], relax="gumbel")
    bank, mosaic = fixed_design("rgbw")
    with pytest.raises(ValueError, match="cfa: set by the design"):
        design_sensor(bank, mosaic, cfa="RGGB")
    with pytest.raises(ValueError, match="name: unknown fixed design"):
        fixed_design("xtrans")
    # shapes, NaNs and degenerate numbers that reached a bare error deep in torch, an overflow or NaN (hard-case
    # audit)
    from isettorch.sensor.filter_bank import check_manufacturable

    wl = torch.arange(400.0, 701.0, 10.0)
    for bad in (torch.full((31,), 0.5), torch.zeros(0, 31), torch.full((1, 3), 0.5)):
        with pytest.raises(ValueError, match=r"filters: expected transmittances \[K >= 1, L = 31\]"):
            check_manufacturable(bad, wl)
    with pytest.raises(ValueError, match="filters: expected strictly increasing wavelengths_nm"):
        check_manufacturable(torch.full((1, 3), 0.5), torch.tensor([400.0, 400.0, 410.0]))
    with pytest.raises(ValueError, match="band_width_nm: expected a positive band width"):
        max_slope_per_nm(3.0, 0.0)
    with pytest.raises(ValueError, match="band_width_nm: expected at least the wavelength grid's step"):
        FilterBank(["learned"], band_width_nm=1e-6)
    with pytest.raises(ValueError, match="band_width_nm: 1e-06 gives 300000001 bands"):
        FilterBank(["R"], band_width_nm=1e-6)
    # fixed filters on a grid coarser than the band width are fine (the band width is the learned filters')
    assert FilterBank(["R", "G", "B"], torch.tensor([450.0, 550.0, 650.0]), learnable=False).filters.shape == (3, 3)
    with pytest.raises(ValueError, match="init_scale: expected a finite number >= 0"):
        LearnedMosaic(["A", "B"], init_scale=math.nan)
    with pytest.raises(ValueError, match=r"temperature: expected a number >= 1e-6"):
        LearnedMosaic(["A", "B"]).temperature = 5e-324
    with pytest.raises(ValueError, match="shape: expected \\(P, Q\\) positive integer sizes"):
        LearnedMosaic(["A", "B"], (2.5, 2))
    with pytest.raises(ValueError, match="height, width: expected positive sizes"):
        LearnedMosaic(["A", "B"]).weights(-1, 4)
    with pytest.raises(ValueError, match="pattern: expected integer filter indices"):
        LearnedMosaic(["A", "B"], pattern=[[0.5, 1.0], [1.0, 0.0]])  # (was truncated to 0)
    with pytest.raises(ValueError, match="step: expected a finite step number"):
        temperature_schedule(math.nan, 10)
    with pytest.raises(TypeError, match="learnable: expected True or False"):
        FilterBank(["learned"], learnable="no")  # (a truthy string made it learnable)
