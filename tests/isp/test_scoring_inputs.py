"""Scores and measurements given inputs they cannot score (an audit of the ISP scoring, chart and metric helpers):
each is refused naming the argument, never a silent wrong number or NaN."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import peak_signal_noise_ratio

from isettorch.isp import evaluation as ev
from isettorch.isp.chart import patch_means
from isettorch.metrics.color import xy_to_xyz
from isettorch.metrics.image_statistics import cross_channel_gradient_correlation, radial_power_spectrum
from isettorch.metrics.snr import dynamic_range_from_curve, snr_uniform


def test_benchmark_cpsnr_takes_the_dtypes_peak_as_scikit_image_does():
    """``isp.evaluation.cpsnr`` passed a peak of 1 to every input: uint8 images with 5 codes of noise scored
    -9.9 dB (scikit-image: 38.2). Now the dtype's peak (255 for uint8), and a float reference outside [0, 1]
    without a peak is refused."""
    rng = np.random.default_rng(0)
    ref = rng.integers(10, 245, (1, 3, 32, 40), dtype=np.uint8)
    est = np.clip(ref.astype(int) + rng.integers(-5, 6, ref.shape), 0, 255).astype(np.uint8)
    expected = peak_signal_noise_ratio(ref, est)  # data_range 255 for uint8
    assert float(ev.cpsnr(torch.from_numpy(est), torch.from_numpy(ref))[0]) == pytest.approx(expected, abs=1e-5)
    with pytest.raises(ValueError, match="data_range: None takes a peak of 1"):
        ev.cpsnr(torch.from_numpy(est).double(), torch.from_numpy(ref).double())
    scaled = ev.cpsnr(torch.from_numpy(est).double(), torch.from_numpy(ref).double(), peak=255.0)
    assert float(scaled[0]) == pytest.approx(expected, abs=1e-9)
    with pytest.raises(ValueError, match="image: expected 3 colour channels"):
        ev.cpsnr(torch.zeros(1, 1, 8, 8), torch.zeros(1, 1, 8, 8))


def test_an_empty_benchmark_is_refused():
    with pytest.raises(ValueError, match="images: expected at least one"):
        ev.evaluate_demosaic([], "bilinear")  # (mean_cpsnr inf for nothing scored)


def test_measurements_refuse_what_they_cannot_measure():
    nan = float("nan")
    xy = torch.tensor([[0.3127, 0.3290], [nan, 0.3]], dtype=torch.float64)
    with pytest.raises(ValueError, match="xy: expected finite"):
        xy_to_xyz(xy, dim=-1)
    with pytest.raises(ValueError, match="Y: expected finite"):
        xy_to_xyz(xy[:1], Y=nan, dim=-1)
    with pytest.raises(ValueError, match="Y: expected a luminance broadcastable"):
        xy_to_xyz(xy[:1], Y=torch.ones(3), dim=-1)
    assert xy_to_xyz(xy[:1], Y=2.0, dim=-1)[0, 1] == 2.0
    img = torch.rand(1, 1, 8, 8, dtype=torch.float64) + 0.5
    for roi in ((0.5, 2.7, 0, 4), (0, 4, 0)):
        with pytest.raises(ValueError, match=r"roi: expected \(row0, row1, col0, col1\) integers"):
            snr_uniform(img, roi=roi)
    with pytest.raises(ValueError, match="image: expected at least 2 pixels"):
        snr_uniform(torch.ones(1, 1))
    # a noise floor at signal 10 (SNR 1 there): a max_signal below it has no dynamic range (it returned -10.65 dB)
    signal = torch.tensor([1.0, 10.0, 100.0, 1000.0], dtype=torch.float64)
    snr = torch.tensor([0.1, 1.0, 10.0, 100.0], dtype=torch.float64)
    assert float(dynamic_range_from_curve(signal, snr)) == pytest.approx(20 * math.log10(100), abs=1e-9)
    with pytest.raises(ValueError, match="max_signal: expected a signal above the noise floor 10"):
        dynamic_range_from_curve(signal, snr, max_signal=5.0)
    chart = torch.rand(1, 3, 24, 36, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"grid: expected \(rows, cols\) integers"):
        patch_means(chart, grid=(4.7, 6))  # (4 rows were measured)
    with pytest.raises(ValueError, match="img: expected finite"):
        patch_means(chart * nan)
    with pytest.raises(ValueError, match="img: expected a floating-point tensor"):
        patch_means((chart * 255).to(torch.uint8))
    rgb = torch.rand(3, 16, 16, dtype=torch.float64)
    with pytest.raises(ValueError, match="a, b: expected channel indices >= 0"):
        cross_channel_gradient_correlation(rgb, a=-1)  # (the last channel)
    f, p = radial_power_spectrum(rgb[0].clone().requires_grad_(True))  # (.numpy() of a graph raised)
    assert np.isfinite(p).all() and len(f) == len(p)
    with pytest.raises(TypeError, match="raw: expected a torch.Tensor"):
        ev.denoise_mosaic(np.zeros((1, 1, 8, 8)), "nlmeans", 0.1)
    with pytest.raises(ValueError, match=r"raw: expected a mosaic \(B, 1, H, W\)"):
        ev.noisy_mosaic(torch.zeros(1, 3, 8, 8), 0.1)


def test_evaluate_demosaic_takes_a_bayer_string():
    """An index-map tensor for RGGB was scored by demosaic_generic's border rule under the name 'bilinear' (26.029
    dB where 'RGGB' gives 26.025 on Kodak 01 at crop 0), and its result's 'pattern' was a tensor (not JSON). The
    string is normalised, as demosaic() does."""
    img = np.random.default_rng(0).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    res = ev.evaluate_demosaic([("a", img)], "bilinear", "rggb", dtype=torch.float64)
    assert res["pattern"] == "RGGB"
    with pytest.raises(TypeError, match=r"^pattern: expected one of \('RGGB'"):
        ev.evaluate_demosaic([("a", img)], "bilinear", torch.tensor([[0, 1], [1, 2]]))
    with pytest.raises(ValueError, match=r"^pattern: expected one of"):
        ev.evaluate_demosaic([("a", img)], "bilinear", "RGBW")
