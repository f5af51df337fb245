"""Image statistics used to check synthetic scenes against published natural-image statistics.

* :func:`power_spectrum_slope`: slope of the radially averaged power spectrum on log-log axes; natural images:
  ~ -2 (van der Schaaf & van Hateren, Vision Res. 36, 1996: -1.88 +- 0.43 over 276 images; Field 1987).
* :func:`gradient_kurtosis`: kurtosis of horizontal/vertical derivatives; natural images are heavy-tailed
  (kurtosis >> 3, a Gaussian's; Huang & Mumford, CVPR 1999; Simoncelli & Olshausen, Annu. Rev. Neurosci. 2001).
* :func:`cross_channel_gradient_correlation`: correlation of the derivatives of two colour channels (high in natural
  images: edges are mostly changes of intensity; Gunturk et al., IEEE SPM 2005 for the demosaicing consequence).
* :func:`detail_ratio_exponent`: how a channel's fine detail scales with the channel's own level, pooled over
  windows: 1 where detail multiplies every channel alike (shading; the constant-hue or colour-ratio demosaicking
  prior: Cok, US patent 4,642,678, 1987; Kimmel, IEEE TIP 8(9), 1999), 0 where it adds the same amount to every
  channel (the colour-difference prior: Hamilton & Adams, US patent 5,629,734, 1997; Pei & Tam, IEEE TCSVT 13(6),
  2003).
* :func:`power_law_exponent_mle`: maximum-likelihood exponent of a truncated power-law sample (dead-leaves radii).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .._checks import check_finite, is_integer

__all__ = ["power_spectrum_slope", "gradient_kurtosis", "cross_channel_gradient_correlation",
           "detail_ratio_exponent", "power_law_exponent_mle", "radial_power_spectrum"]


def _check_image(img: torch.Tensor, name: str = "image") -> torch.Tensor:
    if not isinstance(img, torch.Tensor) or img.dim() != 2 or min(img.shape) < 8:
        raise ValueError(f"{name}: expected a 2-D tensor [H, W] of at least 8 x 8, got "
                         f"{tuple(img.shape) if isinstance(img, torch.Tensor) else type(img).__name__}")
    check_finite(img.detach(), name)
    return img.detach().to(torch.float64)  # (statistics, not differentiable: .numpy() of a graph raised)


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
    if not isinstance(rgb, torch.Tensor):
        raise TypeError(f"rgb: expected a torch.Tensor [C, H, W], got {type(rgb).__name__}")
    if not (is_integer(a) and is_integer(b) and a >= 0 and b >= 0):  # (-1 read as the last channel)
        raise ValueError(f"a, b: expected channel indices >= 0, got {a!r} and {b!r}")
    if rgb.dim() != 3 or rgb.shape[0] <= max(a, b):
        raise ValueError(f"rgb: expected [C, H, W] with channels {a} and {b}, got {tuple(rgb.shape)}")
    check_finite(rgb.detach(), "rgb")

    def grads(c):
        x = rgb[c].to(torch.float64)
        return torch.cat([(x[:, 1:] - x[:, :-1]).reshape(-1), (x[1:] - x[:-1]).reshape(-1)])

    ga, gb = grads(a), grads(b)
    ga, gb = ga - ga.mean(), gb - gb.mean()
    den = float(torch.sqrt((ga * ga).sum() * (gb * gb).sum()))
    if den == 0:
        raise ValueError("rgb: a channel is constant, the correlation is undefined")
    return float((ga * gb).sum()) / den


def _tiles(t: torch.Tensor, window: int) -> torch.Tensor:
    """[C, H, W] -> [C, T, window^2]: the whole ``window`` x ``window`` tiles (a remainder is dropped)."""
    c, h, w = t.shape[0], t.shape[1] // window, t.shape[2] // window
    t = t[:, : h * window, : w * window].reshape(c, h, window, w, window)
    return t.permute(0, 1, 3, 2, 4).reshape(c, h * w, window * window)


def detail_ratio_exponent(images, window: int = 16, min_contrast: float = 0.01, min_correlation: float = 0.8,
                          min_level: float = 0.02) -> tuple[float, int]:
    """(exponent ``beta``, number of window pairs) with ``slope ~ (level ratio)^beta``, fitted by least squares on
    log axes over every ``window`` x ``window`` window of every image and the channel pairs (R, G) and (B, G).

    In a window, ``slope`` is the least-squares gain of channel ``a``'s fine detail (a 4-neighbour Laplacian) on
    channel ``b``'s, and ``level ratio`` the ratio of their window means. Detail that multiplies every channel alike
    (shading) gives ``beta = 1``; detail that adds the same amount to each channel gives ``beta = 0``; a per-image
    scale changes neither (as long as no window crosses ``min_level``). Windows whose detail is weak (Laplacian std
    below ``min_contrast`` of the mean), dark (mean below ``min_level``) or not shared (correlation below
    ``min_correlation``) are skipped.

    Args:
        images: iterable of ``[3, H, W]`` tensors (R, G, B; linear or encoded, the exponent reads differently: a
            power-law encoding keeps 1 at 1 and moves 0 to ``(gamma - 1) / gamma``).
    """
    if isinstance(window, bool) or not isinstance(window, int) or window < 4:
        raise ValueError(f"window: expected an integer >= 4 pixels, got {window!r}")
    xs, ys = [], []
    for n, img in enumerate(images):
        if not isinstance(img, torch.Tensor) or img.dim() != 3 or img.shape[0] != 3 or min(img.shape[1:]) < window + 2:
            raise ValueError(f"images[{n}]: expected a [3, H, W] tensor with H, W >= window + 2, got "
                             f"{tuple(img.shape) if isinstance(img, torch.Tensor) else type(img).__name__}")
        x = img.to(torch.float64)
        lap = 4 * x[:, 1:-1, 1:-1] - x[:, :-2, 1:-1] - x[:, 2:, 1:-1] - x[:, 1:-1, :-2] - x[:, 1:-1, 2:]
        lev = x[:, 1:-1, 1:-1]
        d, m = _tiles(lap, window), _tiles(lev, window).mean(2)  # [3, T, window^2], [3, T]
        d = d - d.mean(2, keepdim=True)
        for a in (0, 2):
            da, db = d[a], d[1]
            saa, sbb, sab = (da * da).sum(1), (db * db).sum(1), (da * db).sum(1)
            sd_a, sd_b = (saa / da.shape[1]).sqrt(), (sbb / da.shape[1]).sqrt()
            ok = ((m[a] > min_level) & (m[1] > min_level) & (sd_a > min_contrast * m[a])
                  & (sd_b > min_contrast * m[1]) & (sab > 0))
            corr = sab / (saa * sbb).clamp_min(1e-300).sqrt()
            ok &= corr > min_correlation
            xs.append((m[a][ok] / m[1][ok]).log())
            ys.append((sab[ok] / sbb[ok]).log())
    xv, yv = torch.cat(xs), torch.cat(ys)
    if xv.numel() < 10 or float(xv.std()) < 1e-3:
        raise ValueError(f"images: {xv.numel()} usable windows with level-ratio spread "
                         f"{float(xv.std()) if xv.numel() > 1 else 0.0:.3g}; need at least 10 with different colours")
    xc = xv - xv.mean()
    return float((xc * (yv - yv.mean())).sum() / (xc * xc).sum()), int(xv.numel())


def power_law_exponent_mle(samples, lo: float, hi: float) -> float:
    """Maximum-likelihood exponent ``alpha`` of ``p(r) ~ r^-alpha`` on ``[lo, hi]`` (truncated power law; the
    score equation of Clauset, Shalizi & Newman, SIAM Rev. 2009, with the truncation term), by bisection."""
    r = np.asarray(samples, dtype=np.float64)
    if (r.size < 2 or not (0 < lo < hi) or not np.isfinite(r).all() or r.min() < lo * (1 - 1e-9)
            or r.max() > hi * (1 + 1e-9)):
        raise ValueError(f"samples: expected >= 2 finite values in [lo, hi] = [{lo}, {hi}]")
    mean_log = float(np.mean(np.log(r / lo)))
    ln = math.log(hi / lo)

    def score(alpha):  # d/d alpha of the mean log-likelihood
        if abs(alpha - 1) < 1e-9:
            return -mean_log + ln / 2
        e = math.exp((1 - alpha) * ln)  # (hi / lo)^(1 - alpha)
        return 1 / (alpha - 1) - mean_log - ln * e / (1 - e)

    lo_a, hi_a = 1.0001, 10.0
    if not score(lo_a) > 0 > score(hi_a):  # the score falls with alpha: its root is outside the bracket
        raise ValueError(f"samples: the maximum-likelihood exponent lies outside ({lo_a}, {hi_a}] (the sample is "
                         f"{'flatter than r^-1' if score(lo_a) <= 0 else 'steeper than r^-10'} on [{lo}, {hi}])")
    for _ in range(200):
        mid = 0.5 * (lo_a + hi_a)
        if score(mid) > 0:
            lo_a = mid
        else:
            hi_a = mid
    return 0.5 * (lo_a + hi_a)
