"""From optical-image irradiance to per-pixel signal: spectral integration with the QE, the
ISETCam Gaussian pre-blur, point sampling at pixel centres (ISETCam) and area integration over
the photodiode aperture (the default).

Geometry (FORMAT.md 4.6 step 3): OI sample ``j`` sits at ``(j - (W2-1)/2) dx_oi`` and sensor pixel
``i`` at ``(i - (cols-1)/2) pitch``; both grids are centred on the optical axis, the same for rows.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .. import spectral
from .._checks import _small_values, is_integer, is_real, tensor_hint

__all__ = [
    "electron_rate_density",
    "isetcam_preblur_size",
    "isetcam_preblur_kernel",
    "isetcam_preblur",
    "pixel_centre_index",
    "sample_point",
    "sample_area",
]


def electron_rate_density(photons: torch.Tensor, qe: torch.Tensor, wavelengths_nm: torch.Tensor,
                          rule: str = "midpoint") -> torch.Tensor:
    """Photo-electrons/s/m^2 per filter: ``sum_lambda photons(lambda) QE_c(lambda) dlambda``.

    ``photons [B, L, H, W]`` (photons/s/m^2/nm), ``qe [C, L]`` (or per item ``[B, C, L]``) -> ``[B, C, H, W]``.
    ``dlambda`` by :func:`isettorch.spectral.wavelength_weights` with ``rule``; multiplied by q this is ISETCam's
    ``SignalCurrentDensity`` (A/m^2) with ``rule='isetcam'`` (or on any uniform grid, where the rules agree).
    """
    b, n_l = photons.shape[:2]
    if qe.dim() not in (2, 3) or qe.shape[-1] != n_l or (qe.dim() == 3 and qe.shape[0] != b):
        raise ValueError(f"qe: expected shape [C, {n_l}] (or [{b}, C, {n_l}] per item) matching photons' batch and "
                         f"wavelengths, got {tuple(qe.shape)}")
    dl = spectral.wavelength_weights(torch.as_tensor(wavelengths_nm), rule).to(photons.device, photons.dtype)
    m = qe.to(photons.dtype) * dl  # [C, L] or [B, C, L]
    h, w = photons.shape[2:]
    return (m @ photons.reshape(b, n_l, h * w)).reshape(b, -1, h, w)  # a contiguous GEMM over the cube


def isetcam_preblur_size(pixel_size_m: float, oi_sample_spacing_m: float) -> int:
    """ISETCam ``regridOI2ISA`` pre-blur size ``k = ceil(pixel pitch / OI sample spacing)``."""
    for name, v in (("pixel_size_m", pixel_size_m), ("oi_sample_spacing_m", oi_sample_spacing_m)):
        if not (math.isfinite(float(v)) and float(v) > 0):  # (0 spacing: ZeroDivisionError; negative: 1)
            raise ValueError(f"{name}: expected a finite length > 0 in metres, got {v!r}")
    return max(1, math.ceil(float(pixel_size_m) / float(oi_sample_spacing_m)))


def isetcam_preblur_kernel(k: int, *, dtype=torch.float64, device=None) -> torch.Tensor:
    """``fspecial('gaussian', [k k], k/4)``: ``exp(-(i^2+j^2)/(2 sigma^2))`` on centred offsets, sum 1 ``[k, k]``."""
    if k < 1:
        raise ValueError(f"k: expected a kernel size >= 1, got {k}")
    sigma = k / 4.0
    o = torch.arange(k, dtype=torch.float64) - (k - 1) / 2
    g = torch.exp(-(o[:, None] ** 2 + o[None, :] ** 2) / (2 * sigma**2))
    # fspecial zeroes entries below eps * max (never reached for sigma = k/4, kept for fidelity).
    g = torch.where(g < torch.finfo(torch.float64).eps * g.max(), torch.zeros_like(g), g)
    return (g / g.sum()).to(dtype=dtype, device=device)


def isetcam_preblur(x: torch.Tensor, k: int) -> torch.Tensor:
    """MATLAB ``conv2(x, G, 'same')`` with G = :func:`isetcam_preblur_kernel` and zero boundary, per channel.

    For even k output sample i is centred on input i + 0.5 (FORMAT.md 4.6 step 2). ``x [B, C, H, W]``.
    """
    if k <= 1:
        return x
    # G = g g^T (a product of two 1-D Gaussians, normalised), so the 2-D convolution is two 1-D passes of k
    # shifted multiply-adds (2k instead of k^2 operations per sample; 3.5x faster at k = 4 on 640^2 x 3); the
    # row sums of G are g. G is symmetric: correlation = convolution.
    g = isetcam_preblur_kernel(k, dtype=torch.float64).sum(1).tolist()
    # conv2 'same' keeps the full convolution from index floor(k/2): input offsets -(k-1-k//2) .. k//2.
    lo, hi = k - 1 - k // 2, k // 2
    h, w = x.shape[-2:]
    xp = F.pad(x, (lo, hi, lo, hi))
    grad = xp.requires_grad
    rows = xp[..., :, 0:w] * g[0]
    for i in range(1, k):
        rows = rows + xp[..., :, i:i + w] * g[i] if grad else rows.add_(xp[..., :, i:i + w], alpha=g[i])
    out = rows[..., 0:h, :] * g[0]
    for i in range(1, k):
        out = out + rows[..., i:i + h, :] * g[i] if grad else out.add_(rows[..., i:i + h, :], alpha=g[i])
    return out


def pixel_centre_index(n_oi: int, n_pixels: int, pixel_size_m, oi_sample_spacing_m: torch.Tensor,
                       offset_m=0.0) -> torch.Tensor:
    """Fractional OI sample index of each pixel centre along one axis ``[B, n_pixels]``.

    ``(n_oi-1)/2 + ((i - (n_pixels-1)/2) pitch + offset) / dx_oi`` (FORMAT.md 4.6 step 3).
    """
    dx = oi_sample_spacing_m.reshape(-1, 1)
    i = torch.arange(n_pixels, dtype=dx.dtype, device=dx.device)
    return (n_oi - 1) / 2 + ((i - (n_pixels - 1) / 2) * pixel_size_m + offset_m) / dx


def _interp_last(x: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """Linear interpolation along the last axis at fractional indices ``pos [B, n]``; 0 outside [0, N-1]."""
    n = x.shape[-1]
    b = x.shape[0]
    if n == 1:
        i0 = torch.zeros_like(pos, dtype=torch.long)
        i1 = i0
        t = torch.zeros_like(pos)
    else:
        i0 = pos.detach().floor().clamp(0, n - 2).long()
        i1 = i0 + 1
        t = pos - i0.to(pos.dtype)
    valid = ((pos >= 0) & (pos <= n - 1)).to(x.dtype)
    t = t.to(x.dtype)
    if pos.shape[0] == 1 or bool((pos == pos[:1]).all()):  # one set of positions: 1-D index_select, no gather
        x0, x1, t0, v0 = x.index_select(-1, i0[0]), x.index_select(-1, i1[0]), t[0], valid[0]
        if x0.requires_grad or t0.requires_grad:
            return (x0 * (1 - t0) + x1 * t0) * v0
        return x0.mul_(1 - t0).add_(x1.mul_(t0)).mul_(v0)  # the same operations, in place
    shape = (b, *x.shape[1:-1], pos.shape[-1])
    view = (b,) + (1,) * (x.dim() - 2) + (pos.shape[-1],)
    x0 = x.gather(-1, i0.reshape(view).expand(shape))
    x1 = x.gather(-1, i1.reshape(view).expand(shape))
    t = t.reshape(view)
    return (x0 * (1 - t) + x1 * t) * valid.reshape(view)


def _check_sampling(x, oi_sample_spacing_m, pixel_size_m, rows, cols) -> None:
    """The public samplers' arguments (their batch shapes, sizes and pitch), checked without a host read of the data:
    a batch-mismatched spacing gave a wrongly shaped result, rows=2.7 three rows, a negative pitch zeros or a mirror,
    an integer image zeros."""
    if not isinstance(x, torch.Tensor) or x.dim() != 4 or not x.is_floating_point():
        raise ValueError(f"x: expected a float tensor [B, C, H, W], got "
                         f"{(x.dtype, tuple(x.shape)) if isinstance(x, torch.Tensor) else type(x).__name__}")
    if not isinstance(oi_sample_spacing_m, torch.Tensor) or oi_sample_spacing_m.numel() not in (1, x.shape[0]):
        raise ValueError(f"oi_sample_spacing_m: expected a tensor of 1 or {x.shape[0]} (the batch) spacings, got "
                         f"{oi_sample_spacing_m!r}")
    # the values where reading them costs no device sync (a CPU batch's few spacings; an OpticalImage checks its
    # own when it is made): a negative spacing gave zeros or a mirrored image, 0 or inf NaN
    values = _small_values(oi_sample_spacing_m.detach())
    if values is not None and not all(math.isfinite(v) and v > 0 for v in values):
        raise ValueError(f"oi_sample_spacing_m: expected finite spacings > 0 (m), got {values}")
    for name, n in (("rows", rows), ("cols", cols)):
        if not (is_integer(n) and n >= 1):
            raise ValueError(f"{name}: expected an integer number of pixels >= 1, got {n!r}")
    if not (is_real(pixel_size_m) and pixel_size_m > 0):  # (a NumPy float32 was refused as not finite)
        raise ValueError(f"pixel_size_m: expected a finite pitch > 0 in metres, got {pixel_size_m!r}"
                         f"{tensor_hint(pixel_size_m)}")


def sample_point(x: torch.Tensor, oi_sample_spacing_m: torch.Tensor, pixel_size_m: float, rows: int, cols: int,
                 ) -> torch.Tensor:
    """Bilinear samples at pixel centres (ISETCam ``interp2(..., 'linear')``; outside the OI -> 0).

    ``x [B, C, H2, W2]`` on the OI grid -> ``[B, C, rows, cols]``.
    """
    _check_sampling(x, oi_sample_spacing_m, pixel_size_m, rows, cols)
    # positions in float64: a float32 index of a wide OI would lose ~1e-4 of a sample
    px = pixel_centre_index(x.shape[-1], cols, pixel_size_m, oi_sample_spacing_m.to(torch.float64))
    py = pixel_centre_index(x.shape[-2], rows, pixel_size_m, oi_sample_spacing_m.to(torch.float64))
    out = _interp_last(x, px)
    return _interp_last(out.transpose(-1, -2), py).transpose(-1, -2)


_BOX_CHUNK = 64  # output pixels per block of the overlap matrix (fastest of 32-512 on 2 CPU cores at 512-2048 px)
_BOX_DENSE_SAMPLES = 4096  # one block of at most _BOX_CHUNK pixels spans every sample up to this many


def _box_mean_constant(x: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Mean of the piecewise-constant signal x (sample m covers [m-0.5, m+0.5]) over [lo, hi] (index units),
    zero outside the image. ``lo, hi [B, n]``, increasing along n. Exact: the overlap of each pixel with each
    sample, as matrix products over blocks of :data:`_BOX_CHUNK` pixels, each with the samples its pixels touch
    (the overlap matrix is banded: the dense one cost O(n^3) per image, 0.86 s for a 2048^2 RGB plane against
    0.08 s). Beyond one block the blocks' sample ranges are read on the host (one transfer of the pixel edges)."""
    n, b, n_out = x.shape[-1], x.shape[0], lo.shape[-1]
    lo64, hi64 = lo.to(torch.float64), hi.to(torch.float64)
    width = hi64 - lo64
    if n_out <= _BOX_CHUNK and n <= _BOX_DENSE_SAMPLES:
        bounds = None  # one block over every sample: no host read (a few pixels over many samples read their range)
    else:
        bounds = torch.stack([lo64.detach().amin(0), hi64.detach().amax(0)]).cpu().tolist()
    parts = []
    for i0 in range(0, n_out, _BOX_CHUNK):
        i1 = min(n_out, i0 + _BOX_CHUNK)
        a, e = 0, n  # the samples [a, e) that the block's pixels overlap (touching ones included, for the ties)
        if bounds is not None:
            a = max(0, math.ceil(min(bounds[0][i0:i1]) - 0.5))
            e = min(n, math.floor(max(bounds[1][i0:i1]) + 0.5) + 1)
        if e <= a:  # the block lies outside the image
            parts.append(x.new_zeros(*x.shape[:-1], i1 - i0))
            continue
        m = torch.arange(a, e, dtype=torch.float64, device=x.device)
        overlap = torch.minimum(hi64[:, i0:i1, None], m + 0.5) - torch.maximum(lo64[:, i0:i1, None], m - 0.5)
        # the positive part as (v + |v|) / 2: the same values, and at a pixel edge on a sample edge (v = 0 for the
        # next sample, minimum / maximum tied for this one) each side's derivative weighs half, the mean of the
        # one-sided derivatives; clamp_min passed the next sample's whole, which with the tie's half gave the
        # spacing's gradient a wrong sign at pitch = 2 x spacing (-0.106 for one-sided +1.29 / +1.13)
        overlap = 0.5 * (overlap + overlap.abs())
        weights = (overlap / width[:, i0:i1, None]).transpose(-1, -2).to(x.dtype)  # [B, e - a, i1 - i0]
        parts.append(torch.matmul(x[..., a:e], weights.reshape(b, *(1,) * (x.dim() - 3), e - a, i1 - i0)))
    return parts[0] if len(parts) == 1 else torch.cat(parts, -1)


def _box_mean_linear(x: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Mean over [lo, hi] (index units, ``lo, hi [B, n]``) of the irradiance reconstructed from the samples of
    ``x`` along its last axis: linear between samples (as ISETCam's ``interp2``), constant over the outer half
    samples, zero beyond (so the integral over the image is the sum of the samples). Exact, via the cumulative
    integral of that piecewise-linear function."""
    n = x.shape[-1]
    b = x.shape[0]
    a = x.to(torch.float64)
    a0, alast = a[..., :1], a[..., -1:]
    trap = torch.cat([torch.zeros_like(a0), (0.5 * (a[..., :-1] + a[..., 1:])).cumsum(-1)], dim=-1)  # [.., n]
    view = (b,) + (1,) * (x.dim() - 2) + (lo.shape[-1],)
    shape = (b, *x.shape[1:-1], lo.shape[-1])

    def integral(edge):  # F(edge) = integral of the reconstruction from -0.5 to edge
        q = edge.to(torch.float64).clamp(-0.5, n - 0.5)
        m = q.detach().floor().clamp(0, max(n - 2, 0)).long()
        u = (q - m.to(q.dtype)).reshape(view)
        q = q.reshape(view)
        idx = m.reshape(view).expand(shape)
        am = a.gather(-1, idx)
        am1 = a.gather(-1, (idx + 1).clamp(max=n - 1))
        mid = 0.5 * a0 + trap.gather(-1, idx) + am * u + (am1 - am) * u * u / 2
        left = (q + 0.5) * a0
        right = 0.5 * a0 + trap[..., -1:] + (q - (n - 1)) * alast
        return torch.where(q < 0, left, torch.where(q >= n - 1, right, mid))

    width = (hi - lo).to(torch.float64).reshape(view)
    return ((integral(hi) - integral(lo)) / width).to(x.dtype)


RECONSTRUCTIONS = {"constant": _box_mean_constant, "linear": _box_mean_linear}


def sample_area(x: torch.Tensor, oi_sample_spacing_m: torch.Tensor, pixel_size_m: float, rows: int, cols: int,
                fill_factor: float = 1.0, reconstruction: str = "constant") -> torch.Tensor:
    """Mean of ``x`` over each pixel's photodiode: a centred square of side ``pitch * sqrt(fill_factor)``.

    ``reconstruction`` says what the irradiance is between OI samples: ``'constant'`` (each sample is the
    mean over its cell, a finite-volume view: a pixel that coincides with a sample returns it) or ``'linear'``
    (bilinear between samples, as ISETCam's point sampling, constant over the outer half samples; small
    photodiodes then tend to point sampling). Zero outside the OI; both conserve the total signal and are
    exact integrals of their model, for pixels larger or smaller than the samples.
    ``x [B, C, H2, W2]`` -> ``[B, C, rows, cols]``.
    """
    _check_sampling(x, oi_sample_spacing_m, pixel_size_m, rows, cols)
    if isinstance(fill_factor, bool) or not 0 < fill_factor <= 1:
        raise ValueError(f"fill_factor: expected a value in (0, 1], got {fill_factor}")
    if reconstruction not in RECONSTRUCTIONS:
        raise ValueError(f"reconstruction: expected one of {sorted(RECONSTRUCTIONS)}, got {reconstruction!r}")
    box = RECONSTRUCTIONS[reconstruction]
    # one spacing for a batch is every item's (the box means take one row of pixel edges per item)
    oi_sample_spacing_m = oi_sample_spacing_m.reshape(-1).expand(x.shape[0])
    dx = oi_sample_spacing_m.reshape(-1, 1).to(torch.float64)
    half = pixel_size_m * math.sqrt(fill_factor) / 2 / dx
    px = pixel_centre_index(x.shape[-1], cols, pixel_size_m, oi_sample_spacing_m.to(torch.float64))
    py = pixel_centre_index(x.shape[-2], rows, pixel_size_m, oi_sample_spacing_m.to(torch.float64))
    out = box(x, px - half, px + half)
    return box(out.transpose(-1, -2), py - half, py + half).transpose(-1, -2)
