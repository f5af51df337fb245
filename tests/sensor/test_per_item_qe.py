"""Per-item (batched) spectral QE: ``shifted_qe`` and a per-call ``spectral_qe`` with one curve set per item.

References: every batched result is compared with B single-item computations through the existing one-QE path (each
item of the optical image alone, ``oi[i]``, captured by a Sensor built with that item's own unbatched SpectralQE),
and the shifted curves with ``spectral.resample`` and with an exact translation by whole grid steps.
"""

from __future__ import annotations

import pytest
import torch

from isettorch import spectral
from isettorch.optics import DiffractionLimitedOptics
from isettorch.optics.optical_image import OpticalImage
from isettorch.scene import Scene
from isettorch.sensor import CFA, Sensor, SpectralQE, filter_set, shifted_qe

WAVE = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
SHIFTS = torch.tensor([[4.0, -3.5, 0.0], [-10.0, 7.25, 9.5], [0.0, 0.0, 0.0]], dtype=torch.float64)


def test_resample_rows_equals_spectral_resample_bitwise():
    """The per-row search is ``spectral.resample`` row by row, bitwise (shifted grids, points outside, shift 0)."""
    g = torch.Generator().manual_seed(0)
    src = torch.cumsum(torch.rand(5, 12, generator=g, dtype=torch.float64) * 20 + 1, 1) + 380
    src[2] = torch.arange(12, dtype=torch.float64) * 10 + 400  # equal to dst: resample's copy shortcut
    vals = torch.rand(5, 12, generator=g, dtype=torch.float64)
    dst = torch.arange(12, dtype=torch.float64) * 10 + 400
    out = spectral.resample_rows(vals, src, dst)
    for i in range(5):
        assert torch.equal(out[i], spectral.resample(vals[i], src[i], dst)), i


def test_shifted_qe_is_the_translated_curve():
    """A shift of one native grid step moves every sample one step (exact: the interpolation hits the samples),
    with 0 where the shifted curve has no data; a [B, C] shift gives each item the curve of its own [C] shift."""
    w, vals, letters = filter_set("nikon_5100", dtype=torch.float64)
    step = float(w[1] - w[0])
    assert torch.allclose(w[1:] - w[:-1], torch.full_like(w[1:], step))  # a uniform native grid
    qe = shifted_qe(CFA("RGGB"), "nikon_5100", torch.tensor([step, 0.0, -step], dtype=torch.float64))
    f = qe.native()
    assert qe.batch_size is None and f.shape == vals.shape
    assert torch.equal(f[0, 1:], vals[0, :-1]) and float(f[0, 0]) == 0.0  # R moved to longer wavelengths
    assert torch.equal(f[1], vals[1])
    assert torch.equal(f[2, :-1], vals[2, 1:]) and float(f[2, -1]) == 0.0
    # half a step: the mean of neighbours (linear interpolation)
    half = shifted_qe(CFA("RGGB"), "nikon_5100", torch.tensor([0.5 * step] * 3, dtype=torch.float64)).native()
    torch.testing.assert_close(half[:, 1:], 0.5 * (vals[:, 1:] + vals[:, :-1]), rtol=1e-15, atol=1e-15)
    batched = shifted_qe(CFA("GRBG"), "nikon_5100", SHIFTS)
    assert batched.batch_size == 3
    on_grid = batched(WAVE)
    assert on_grid.shape == (3, 3, WAVE.numel())
    for i in range(3):
        one = shifted_qe(CFA("GRBG"), "nikon_5100", SHIFTS[i])
        assert torch.equal(batched.native()[i], one.native())
        assert torch.equal(on_grid[i], one(WAVE))
        for c in range(3):  # the set's curve resampled from its shifted grid
            assert torch.equal(one.native()[c], spectral.resample(vals[c], w + SHIFTS[i, c], w))


def test_shifted_qe_bad_input_is_named():
    with pytest.raises(ValueError, match="shift_nm"):
        shifted_qe(CFA("RGGB"), "nikon_5100", torch.zeros(2, 4))
    with pytest.raises(ValueError, match="shift_nm"):
        shifted_qe(CFA("RGGB"), "nikon_5100", torch.tensor([float("nan"), 0.0, 0.0]))
    with pytest.raises(ValueError, match="filters"):
        shifted_qe(CFA("RGBW"), "nikon_5100", 0.0)
    with pytest.raises(TypeError, match="cfa"):
        shifted_qe("RGGB", "nikon_5100", 0.0)


def _scene(n_terms: int, b: int = 3):
    g = torch.Generator().manual_seed(n_terms)
    maps = torch.rand(b, n_terms, 20, 20, generator=g, dtype=torch.float64)
    spectra = torch.rand(b, n_terms, WAVE.numel(), generator=g, dtype=torch.float64) * 1e16
    return Scene.from_factors(maps, spectra, WAVE, hfov_deg=torch.tensor([2.0, 2.5, 3.0][:b], dtype=torch.float64),
                              distance_m=1.5)


def _sensor(spectral_qe=None):
    return Sensor(rows=12, cols=12, pixel_size_m=2e-6, cfa="GRBG", adc_bits=12, spectral_qe=spectral_qe)


def _item_qe(i: int) -> SpectralQE:
    """Item i's QE as an independent unbatched module (the same curves, its own SpectralQE)."""
    return shifted_qe(CFA("GRBG"), "nikon_5100", SHIFTS[i])


@pytest.mark.parametrize("pad_mode", ["zero", "isetcam"])
@pytest.mark.parametrize("n_terms", [1, 4])
@pytest.mark.parametrize("extra", [False, True])
def test_batched_qe_equals_per_item_calls(n_terms, extra, pad_mode):
    """Channel rates (with and without extra weightings: both orders of the Fourier-domain projection, J K small
    and large) and the noise-free capture of a batch with per-item QE equal B single-item calls: each item of the
    optical image alone (its Fourier factors, projected on ``[L, K]`` weights) captured by a sensor holding that
    item's QE."""
    scene = _scene(n_terms)
    optics = DiffractionLimitedOptics(f_number=2.8, focal_length_m=4e-3, pad_mode=pad_mode).to(torch.float64)
    oi = optics(scene)
    assert oi.is_factored
    qe = shifted_qe(CFA("GRBG"), "nikon_5100", SHIFTS)
    peak = torch.tensor([0.4, 0.5, 0.6], dtype=torch.float64)
    xyz = torch.rand(WAVE.numel(), 3, generator=torch.Generator().manual_seed(5), dtype=torch.float64) * 1e-3
    ew = xyz if extra else None
    sensor = _sensor()
    rates, x = sensor.channel_rates(oi, ew, qe_scale=peak, spectral_qe=qe)
    raw = sensor(oi, noise=False, exposure_s=1e-3, qe_scale=peak, spectral_qe=qe)
    assert raw.spectral_qe is qe
    for i in range(3):
        oi_i = oi[i]
        ref = _sensor(_item_qe(i))
        r_i, x_i = ref.channel_rates(oi_i, ew, qe_scale=float(peak[i]))
        torch.testing.assert_close(rates[i:i + 1], r_i, rtol=1e-11, atol=1e-11 * float(r_i.max()))
        if extra:
            torch.testing.assert_close(x[i:i + 1], x_i, rtol=1e-11, atol=1e-11 * float(x_i.max()))
        raw_i = ref(oi_i, noise=False, exposure_s=1e-3, qe_scale=float(peak[i]))
        torch.testing.assert_close(raw.noise_free[i:i + 1], raw_i.noise_free, rtol=1e-11, atol=1e-8)
    # the items' QE differ: a batch-wide QE would not give these rates
    shared, _ = sensor.channel_rates(oi, ew, qe_scale=peak)
    assert float((shared - rates).abs().max()) > 1e-3 * float(rates.max())


def test_batched_qe_dense_image_and_spectral_etendue():
    """A dense optical image (the sampling module's QE integral) and wavelength-dependent pixel optics (band by
    band) with a per-item QE equal per-item sensors, and qe/spectral_weights give each item's curves."""
    g = torch.Generator().manual_seed(1)
    wave = WAVE[::5].contiguous()  # 7 bands: the pixel optics evaluate a diffraction etendue per band
    photons = torch.rand(3, wave.numel(), 12, 12, generator=g, dtype=torch.float64) * 1e17
    oi = OpticalImage(photons, wave, sample_spacing_m=2e-6, f_number=2.0, focal_length_m=4e-3)
    qe = shifted_qe(CFA("GRBG"), "nikon_5100", SHIFTS)
    po = {"method": "centred", "diffraction": True, "layer_thicknesses_m": [1e-6, 2e-6], "layer_indices": [1.46, 1.6],
          "microlens_focal_length_m": 3e-6}
    for kw in ({}, {"pixel_optics": po}):
        sensor = Sensor(rows=12, cols=12, pixel_size_m=2e-6, cfa="GRBG", **kw)
        rates, _ = sensor.channel_rates(oi, spectral_qe=qe)
        assert sensor.qe(oi, qe).shape == (3, 3, wave.numel())
        assert sensor.spectral_weights(oi, qe).shape == (3, wave.numel(), 3)
        for i in range(3):
            ref = Sensor(rows=12, cols=12, pixel_size_m=2e-6, cfa="GRBG", spectral_qe=_item_qe(i), **kw)
            r_i, _ = ref.channel_rates(oi[i])
            torch.testing.assert_close(rates[i:i + 1], r_i, rtol=1e-12, atol=0)
            assert torch.equal(sensor.qe(oi, qe)[i], ref.qe(oi[i]))


def test_per_item_projection_gradient():
    """The per-item Fourier-domain projection back-propagates to each item's weights what the one-weighting
    projection of that item alone does (both summation orders: J K small and large)."""
    for n_terms, k in ((1, 3), (4, 6)):
        scene = _scene(n_terms, b=2)
        factors = DiffractionLimitedOptics(f_number=2.8, focal_length_m=4e-3).to(torch.float64)(scene).factors
        g = torch.Generator().manual_seed(k)
        w = torch.rand(2, WAVE.numel(), k, generator=g, dtype=torch.float64, requires_grad=True)
        probe = torch.rand(2, k, *factors.shape[1:], generator=g, dtype=torch.float64)
        (grad,) = torch.autograd.grad((factors.project(w) * probe).sum(), w)
        for i in range(2):
            w_i = w[i].detach().clone().requires_grad_(True)
            (grad_i,) = torch.autograd.grad((factors.select(slice(i, i + 1)).project(w_i) * probe[i]).sum(), w_i)
            torch.testing.assert_close(grad[i], grad_i, rtol=1e-11, atol=1e-11 * float(grad_i.abs().max()))


def test_bad_per_call_qe_is_named():
    sensor = _sensor()
    oi = DiffractionLimitedOptics(f_number=2.8, focal_length_m=4e-3).to(torch.float64)(_scene(1))
    with pytest.raises(ValueError, match="spectral_qe"):
        sensor(oi, spectral_qe=shifted_qe(CFA("GRBG"), "nikon_5100", SHIFTS[:2]))
    with pytest.raises(ValueError, match="spectral_qe"):
        sensor(oi, spectral_qe=SpectralQE(torch.ones(1, 2), [400.0, 700.0], ["W"]))
    with pytest.raises(TypeError, match="spectral_qe"):
        sensor(oi, spectral_qe=torch.ones(3, 3, 31))
    with pytest.raises(ValueError, match="weights"):
        oi.factors.project(torch.ones(2, WAVE.numel(), 3, dtype=torch.float64))
