"""Image statistics used to check synthetic scenes against published natural-image statistics.

* :func:`power_spectrum_slope`: slope of the radially averaged power spectrum on log-log axes; natural images:
  ~ -2 (van der Schaaf & van Hateren, Vision Res. 36, 1996: -1.88 +- 0.43 over 276 images; Field 1987).
* :func:`gradient_kurtosis`: kurtosis of horizontal/vertical derivatives; natural images are heavy-tailed
  (kurtosis >> 3, a Gaussian's; Huang & Mumford, CVPR 1999; Simoncelli & Olshausen, Annu. Rev. Neurosci. 2001).
* :func:`cross_channel_gradient_correlation`: correlation of the derivatives of two colour channels (high in natural
  images: edges are mostly changes of intensity; Gunturk et al., IEEE SPM 2005 for the demosaicing consequence).
* :func:`power_law_exponent_mle`: maximum-likelihood exponent of a truncated power-law sample (dead-leaves radii).
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["power_spectrum_slope", "gradient_kurtosis", "cross_channel_gradient_correlation",
           "power_law_exponent_mle", "radial_power_spectrum"]


def _check_image(img: torch.Tensor, name: str = "image") -> torch.Tensor:
    if not isinstance(img, torch.Tensor) or img.dim() != 2 or min(img.shape) < 8:
        raise ValueError(f"{name}: expected a 2-D tensor [H, W] of at least 8 x 8, got "
                         f"{tuple(img.shape) if isinstance(img, torch.Tensor) else type(img).__name__}")
    return img.to(torch.float64)


def radial_power_spectrum(img: torch.Tensor, *, window: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies in cycles/pixel, radially averaged power) of ``img`` [H, W] (mean removed, Hann window)."""
    x = _check_image(img)
    x = x - x.mean()
    h, w = x.shape
    if window:
        x = x * torch.hann_window(h, periodic=False, dtype=x.dtype)[:, None] * \
            torch.hann_window(w, periodic=False, dtype=x.dtype)[None, :]
    p = torch.fft.fft2(x).abs().pow(2).numpy()
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    f = np.sqrt(fx * fx + fy * fy)
    n = min(h, w)
    bins = np.arange(1, n // 2 + 1) / n  # annuli 1/n wide up to Nyquist
    idx = np.digitize(f.ravel(), bins)
    sums = np.bincount(idx, weights=p.ravel(), minlength=bins.size + 1)
    counts = np.bincount(idx, minlength=bins.size + 1)
    centres = (np.arange(bins.size + 1) + 0.5) / n
    keep = (counts > 0) & (np.arange(bins.size + 1) >= 1) & (np.arange(bins.size + 1) < bins.size)
    return centres[keep], sums[keep] / counts[keep]


def power_spectrum_slope(img: torch.Tensor, f_range=(4.0, 0.25)) -> float:
    """Least-squares slope of log power against log frequency over ``f_range`` = (lowest frequency in cycles per
    image, highest in cycles per pixel); the default skips the lowest 4 cycles/image (window leakage) and stays
    below a Bayer sensor's per-colour Nyquist (0.25 cycles/pixel)."""
    f, p = radial_power_spectrum(img)
    n = min(img.shape)
    keep = (f >= f_range[0] / n) & (f <= f_range[1]) & (p > 0)
    if keep.sum() < 3:
        raise ValueError(f"f_range: fewer than 3 frequency bins in {f_range} for an image of {tuple(img.shape)}")
    return float(np.polyfit(np.log(f[keep]), np.log(p[keep]), 1)[0])


def gradient_kurtosis(img: torch.Tensor) -> float:
    """Kurtosis (4th standardised moment, 3 for a Gaussian) of the horizontal and vertical first differences."""
    x = _check_image(img)
    d = torch.cat([(x[:, 1:] - x[:, :-1]).reshape(-1), (x[1:] - x[:-1]).reshape(-1)])
    d = d - d.mean()
    var = float((d * d).mean())
    if var <= 0:
        raise ValueError("image: constant image, the gradient kurtosis is undefined")
    return float((d**4).mean()) / var**2


def cross_channel_gradient_correlation(rgb: torch.Tensor, a: int = 0, b: int = 1) -> float:
    """Pearson correlation of the first differences (horizontal and vertical) of channels ``a`` and ``b`` of
    ``rgb`` [C, H, W]."""
    if rgb.dim() != 3 or rgb.shape[0] <= max(a, b):
        raise ValueError(f"rgb: expected [C, H, W] with channels {a} and {b}, got {tuple(rgb.shape)}")

    def grads(c):
        x = rgb[c].to(torch.float64)
        return torch.cat([(x[:, 1:] - x[:, :-1]).reshape(-1), (x[1:] - x[:-1]).reshape(-1)])

    ga, gb = grads(a), grads(b)
    ga, gb = ga - ga.mean(), gb - gb.mean()
    den = float(torch.sqrt((ga * ga).sum() * (gb * gb).sum()))
    if den == 0:
        raise ValueError("rgb: a channel is constant, the correlation is undefined")
    return float((ga * gb).sum()) / den


def power_law_exponent_mle(samples, lo: float, hi: float) -> float:
    """Maximum-likelihood exponent ``alpha`` of ``p(r) ~ r^-alpha`` on ``[lo, hi]`` (truncated power law; the
    score equation of Clauset, Shalizi & Newman, SIAM Rev. 2009, with the truncation term), by bisection."""
    r = np.asarray(samples, dtype=np.float64)
    if r.size < 2 or not (0 < lo < hi) or r.min() < lo * (1 - 1e-9) or r.max() > hi * (1 + 1e-9):
        raise ValueError(f"samples: expected >= 2 values in [lo, hi] = [{lo}, {hi}]")
    mean_log = float(np.mean(np.log(r / lo)))
    ln = math.log(hi / lo)

    def score(alpha):  # d/d alpha of the mean log-likelihood
        if abs(alpha - 1) < 1e-9:
            return -mean_log + ln / 2
        e = math.exp((1 - alpha) * ln)  # (hi / lo)^(1 - alpha)
        return 1 / (alpha - 1) - mean_log - ln * e / (1 - e)

    lo_a, hi_a = 1.0001, 10.0
    for _ in range(200):
        mid = 0.5 * (lo_a + hi_a)
        if score(mid) > 0:
            lo_a = mid
        else:
            hi_a = mid
    return 0.5 * (lo_a + hi_a)
