"""Procedural textures (scene content) for the natural-scene generator (:mod:`isettorch.data.natural`); each
draws only from its generator.

* :func:`power_law_noise`: Gaussian noise with amplitude spectrum ``|f|^-s`` (power ``|f|^-2s``): natural images
  have ``s ~ 1`` (Field, JOSA A 4, 1987; van der Schaaf & van Hateren, Vision Res. 36, 1996).
* :func:`warped_grating`: a sine grating whose phase is displaced by smooth power-law noise (wood grain, fabric,
  ripples: oriented texture that is not perfectly periodic).
* :func:`colour_line_weights`: mixing weights in [0, 1] between two materials, so that a region's colours lie on a
  line in colour space (the colour-lines model of Omer & Werman, CVPR 2004).
"""

from __future__ import annotations

import math

import torch

__all__ = ["power_law_noise", "power_law_noise_on_boxes", "normal_cdf", "warped_grating", "colour_line_weights"]


def power_law_noise(h: int, w: int, exponent, generator: torch.Generator, *, dtype=torch.float32,
                    device=None) -> torch.Tensor:
    """Zero-mean, unit-std Gaussian field ``[h, w]`` with radial amplitude spectrum ``|f|^-exponent`` (power
    spectrum slope ``-2 exponent`` on log-log axes); periodic (FFT synthesis), DC removed.

    ``exponent`` a ``[B]`` tensor gives ``B`` fields ``[B, h, w]`` at once, each with its own exponent, drawn with
    ``generator`` on ``device`` (the batched scene generator, :mod:`isettorch.data.batched_natural`).

    Example:
        >>> power_law_noise(64, 64, 1.0, torch.Generator().manual_seed(0)).shape
        torch.Size([64, 64])
    """
    if h < 2 or w < 2:
        raise ValueError(f"h, w: expected at least 2 x 2, got {h} x {w}")
    batched = isinstance(exponent, torch.Tensor) and exponent.dim() == 1
    e = exponent.to(torch.float64) if batched else float(exponent)
    if not bool(((e >= 0) & (e <= 4)).all()) if batched else not 0 <= e <= 4:
        raise ValueError(f"exponent: expected a spectral exponent in [0, 4], got {exponent}")
    fy = torch.fft.fftfreq(h, dtype=torch.float64, device=device)[:, None]
    fx = torch.fft.rfftfreq(w, dtype=torch.float64, device=device)[None, :]
    f = torch.sqrt(fx * fx + fy * fy)
    if batched:
        amp = torch.where(f > 0, f.clamp_min(1e-12)[None] ** -e[:, None, None], torch.zeros((), dtype=f.dtype,
                                                                                            device=f.device))
    else:
        amp = torch.where(f > 0, f.clamp_min(1e-12) ** -e, torch.zeros_like(f))
    shape = (e.numel(), h, w) if batched else (h, w)
    white = torch.randn(shape, generator=generator, dtype=torch.float64, device=device)
    x = torch.fft.irfft2(torch.fft.rfft2(white) * amp, s=(h, w))
    std = x.flatten(1).std(1)[:, None, None] if batched else x.std()
    return (x / std.clamp_min(1e-12)).to(dtype)


def power_law_noise_on_boxes(hh: torch.Tensor, ww: torch.Tensor, ly: torch.Tensor, lx: torch.Tensor,
                             inside: torch.Tensor, exponent: torch.Tensor, generator: torch.Generator,
                             size: tuple[int, int] | None = None) -> torch.Tensor:
    """:func:`power_law_noise` on each item's own ``hh_b x ww_b`` periodic grid (boxes of different sizes in one
    batch), evaluated at local coordinates ``ly [B, wy]``, ``lx [B, wx]`` (integers, the box's pixels at
    0..hh-1) and normalised to unit std over the box pixels (``inside [B, wy, wx]``). Returns ``[B, wy, wx]``
    float64.

    Synthesis ``Re sum_k A(k) Z_k exp(2 pi i (ky y / hh + kx x / ww))`` with ``Z_k`` standard complex Gaussians
    over each item's full DFT grid (``k`` from ``-(n // 2)`` to ``(n - 1) // 2``, the frequencies of
    ``torch.fft.fftfreq``): covariance ``(1/2) sum_k A^2 cos(2 pi f d)``, proportional to the FFT synthesis'
    (Field 1987's 1/f^s spectrum on the same grid), so the normalised fields have the same distribution.
    ``size``: ``(hh.max(), ww.max())`` when the caller has read them (two host reads fewer)."""
    dev = ly.device
    my, mx = (int(hh.max()), int(ww.max())) if size is None else size
    jy, jx = torch.arange(my, device=dev), torch.arange(mx, device=dev)
    ky = (jy[None] - torch.div(hh, 2, rounding_mode="floor")[:, None]).to(torch.float64)
    kx = (jx[None] - torch.div(ww, 2, rounding_mode="floor")[:, None]).to(torch.float64)
    fy, fx = ky / hh[:, None], kx / ww[:, None]
    valid = (jy[None] < hh[:, None])[:, :, None] & (jx[None] < ww[:, None])[:, None, :]
    f = torch.sqrt(fy[:, :, None] ** 2 + fx[:, None, :] ** 2)
    amp = torch.where(valid & (f > 0), f.clamp_min(1e-12) ** -exponent[:, None, None],
                      torch.zeros((), dtype=torch.float64, device=dev))
    nb = hh.shape[0]
    z = torch.complex(torch.randn(nb, my, mx, generator=generator, device=dev, dtype=torch.float64),
                      torch.randn(nb, my, mx, generator=generator, device=dev, dtype=torch.float64)) * amp
    ey = torch.exp(2j * math.pi * ly.to(torch.float64)[:, :, None] * fy[:, None, :])  # [B, wy, my]
    ex = torch.exp(2j * math.pi * lx.to(torch.float64)[:, :, None] * fx[:, None, :])  # [B, wx, mx]
    x = (ey @ z @ ex.transpose(1, 2)).real
    cnt = inside.sum((1, 2)).clamp_min(2)
    mean = (x * inside).sum((1, 2)) / cnt
    var = (((x - mean[:, None, None]) * inside) ** 2).sum((1, 2)) / (cnt - 1)
    return x / var.sqrt().clamp_min(1e-12)[:, None, None]


def normal_cdf(x: torch.Tensor) -> torch.Tensor:
    """Standard normal CDF ``(1 + erf(x / sqrt 2)) / 2`` (the colour-line weights' mapping)."""
    return 0.5 * (1 + torch.erf(x / math.sqrt(2)))


def warped_grating(h: int, w: int, frequency_cpp: float, angle_rad: float, warp_px: float,
                   generator: torch.Generator, *, warp_exponent: float = 2.0, dtype=torch.float32) -> torch.Tensor:
    """``0.5 + 0.5 sin(2 pi f (u + d(x)) + phi)`` in [0, 1], ``u`` the coordinate along ``angle_rad``, ``d`` a
    smooth power-law displacement field (``|f|^-warp_exponent``) of std ``warp_px`` pixels, ``phi`` uniform. Sampled
    at the pixel centres, so up to the Nyquist frequency, 0.5 cycles/pixel (above it the grating aliases: 0.75 came
    out as 0.25, 1 and 2 as a constant: refused)."""
    if not 0 < frequency_cpp <= 0.5:
        raise ValueError(f"frequency_cpp: expected (0, 0.5] cycles/pixel (sampled at pixel centres), got "
                         f"{frequency_cpp}")
    y = torch.arange(h, dtype=torch.float64)[:, None]
    x = torch.arange(w, dtype=torch.float64)[None, :]
    u = x * math.cos(angle_rad) + y * math.sin(angle_rad)
    d = power_law_noise(h, w, warp_exponent, generator, dtype=torch.float64) * float(warp_px)
    phi = 2 * math.pi * float(torch.rand((), generator=generator, dtype=torch.float64))
    return (0.5 + 0.5 * torch.sin(2 * math.pi * frequency_cpp * (u + d) + phi)).to(dtype)


def colour_line_weights(h: int, w: int, exponent: float, generator: torch.Generator, *, contrast: float = 1.0,
                        dtype=torch.float32) -> torch.Tensor:
    """Weights ``t`` in [0, 1] ``[h, w]``: the normal CDF of ``contrast`` x :func:`power_law_noise`; a material
    blend ``(1 - t) R_a + t R_b`` then has colours on the segment between two colours (Omer & Werman 2004)."""
    n = power_law_noise(h, w, exponent, generator, dtype=torch.float64) * float(contrast)
    return normal_cdf(n).to(dtype)
