"""FFT application of a shift-invariant OTF as a linear convolution, with padding only as wide as the PSF.

Layout: images ``[B, L, H, W]``; an OTF callback ``otf_fn(fy [B, My], fx [B, Mx // 2 + 1]) -> [B|1, L, My, Mx//2+1]``
gets the FFT frequencies in cycles/m of each batch sample's grid (spacing ``dx [B]``) and returns the transfer
function there (real, or complex for asymmetric PSFs), with DC at index 0.

Two cases:

* **full output** (``window=None``): the image is padded by at least ``margin`` samples per side (rounded up to
  an FFT-friendly size), the OTF is applied on that padded grid and the **whole padded grid is returned**.
  The transfer function at every FFT frequency is exactly the OTF, and power is conserved exactly (the kernel
  sums to OTF(0) = 1 and nothing is cropped). Light further than ``margin`` from the image would wrap around
  to the other side; ``margin`` is chosen so that this is below the optics' ``psf_tolerance``. With ``'edge'``
  padding, whose border continues beyond the padding, the whole output is computed as a window (below).
* **window** ``(top, left, height, width)`` in the coordinates of that full output: only the window is
  computed, from the sources within ``margin`` of it, on a buffer large enough that nothing wraps around into
  the window (the error is the PSF energy beyond ``margin``).

Pad modes: ``'zero'`` (nothing outside the scene), ``'mean'`` (each wavelength's mean), ``'edge'`` (replicate
the border), or a number (a constant fill).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["next_fast_size", "full_padding", "blur_fft", "fft_buffer", "fft_frequencies", "PAD_MODES"]

PAD_MODES = ("zero", "mean", "edge")


def next_fast_size(n: int, parity: int | None = None) -> int:
    """Smallest ``m >= n`` whose prime factors are 2, 3, 5 (and ``m % 2 == parity`` if given)."""
    m = max(int(n), 1)
    while True:
        if parity is None or m % 2 == parity:
            k = m
            for p in (2, 3, 5):
                while k % p == 0:
                    k //= p
            if k == 1:
                return m
        m += 1


def full_padding(size: int, margin: int) -> int:
    """Per-side padding of the full output: at least ``margin``, with ``size + 2 pad`` an FFT-friendly size."""
    if margin <= 0:
        return 0
    return (next_fast_size(size + 2 * margin, parity=size % 2) - size) // 2


def _check_pad_mode(pad_mode) -> None:
    if not (pad_mode in PAD_MODES or isinstance(pad_mode, (int, float)) and not isinstance(pad_mode, bool)):
        raise ValueError(f"pad_mode: expected one of {PAD_MODES} or a number, got {pad_mode!r}")


def _fill_value(x: torch.Tensor, pad_mode) -> torch.Tensor | None:
    if pad_mode == "zero":
        return torch.zeros((), dtype=x.dtype, device=x.device)
    if pad_mode == "mean":
        return x.mean(dim=(-2, -1), keepdim=True)
    if pad_mode == "edge":
        return None
    if isinstance(pad_mode, (int, float)) and not isinstance(pad_mode, bool):
        return torch.as_tensor(float(pad_mode), dtype=x.dtype, device=x.device)
    raise ValueError(f"pad_mode: expected one of {PAD_MODES} or a number, got {pad_mode!r}")


def extend(x: torch.Tensor, rows: tuple[int, int], cols: tuple[int, int], pad_mode) -> torch.Tensor:
    """The image on rows ``[r0, r1)`` and cols ``[c0, c1)`` of its infinite extension by ``pad_mode``."""
    h, w = x.shape[-2:]
    (r0, r1), (c0, c1) = rows, cols
    # the part of the window inside the image, then F.pad for the rest (5x faster than gathering indices)
    ir0, ir1, ic0, ic1 = max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)
    if ir1 <= ir0 or ic1 <= ic0:  # the window lies wholly outside the image
        return _extend_gather(x, rows, cols, _fill_value(x, pad_mode))
    core = x[..., ir0:ir1, ic0:ic1]
    pads = (ic0 - c0, c1 - ic1, ir0 - r0, r1 - ir1)
    if not any(pads):
        _check_pad_mode(pad_mode)
        return core
    if pad_mode == "zero":
        return F.pad(core, pads, mode="constant", value=0.0)
    fill = _fill_value(x, pad_mode)
    if fill is None:  # edge
        flat = core.reshape(-1, 1, *core.shape[-2:])
        return F.pad(flat, pads, mode="replicate").reshape(*core.shape[:-2], r1 - r0, c1 - c0)
    if fill.dim() == 0:
        return F.pad(core, pads, mode="constant", value=float(fill))
    outside = F.pad(torch.zeros(core.shape[-2:], dtype=x.dtype, device=x.device), pads, value=1.0)
    return F.pad(core, pads) + fill * outside


def _extend_gather(x: torch.Tensor, rows: tuple[int, int], cols: tuple[int, int], fill) -> torch.Tensor:
    h, w = x.shape[-2:]
    ri = torch.arange(rows[0], rows[1], device=x.device)
    ci = torch.arange(cols[0], cols[1], device=x.device)
    out = x.index_select(-2, ri.clamp(0, h - 1)).index_select(-1, ci.clamp(0, w - 1))
    if fill is None:  # edge
        return out
    inside = ((ri >= 0) & (ri < h))[:, None] & ((ci >= 0) & (ci < w))[None, :]
    return torch.where(inside, out, fill)


def _convolve(buf: torch.Tensor, otf_fn, dx: torch.Tensor) -> torch.Tensor:
    my, mx = buf.shape[-2:]
    fy, fx = fft_frequencies(my, mx, dx, dtype=buf.dtype, device=buf.device)
    otf = otf_fn(fy, fx)
    return torch.fft.irfft2(torch.fft.rfft2(buf) * otf, s=(my, mx))


def fft_buffer(x: torch.Tensor, margin: tuple[int, int], pad_mode="zero",
               window: tuple[int, int, int, int] | None = None
               ) -> tuple[torch.Tensor, tuple[int, int], tuple[int, int, int, int]]:
    """The padded buffer :func:`blur_fft` transforms, the full output's padding and where the output lies in it.

    Returns ``(buf (B, C, My, Mx), (pad_rows, pad_cols), (r0, c0, height, width))``: the blurred image is
    ``irfft2(rfft2(buf) * OTF)[..., r0:r0 + height, c0:c0 + width]``. Linear in ``x`` for the pad modes
    ``'zero'``, ``'mean'`` and ``'edge'`` (so a sum of images may be buffered term by term).
    """
    h, w = x.shape[-2:]
    pr, pc = full_padding(h, margin[0]), full_padding(w, margin[1])
    _check_pad_mode(pad_mode)
    if window is None:
        if pad_mode != "edge" or max(margin) <= 0:
            buf = extend(x, (-pr, h + pr), (-pc, w + pc), pad_mode)
            return buf, (pr, pc), (0, 0, h + 2 * pr, w + 2 * pc)
        # 'edge': the border's values continue beyond the padding, where a circular FFT of the padded grid alone
        # wraps the opposite border's light into the outer margin (0.40 of a 0 | 1 step's far side where it is 0,
        # 0.77 where it is 1): the whole output as a window, whose buffer reaches the margin further
        window = (0, 0, h + 2 * pr, w + 2 * pc)
    top, left, wh, ww = window
    if not (wh >= 1 and ww >= 1 and top >= 0 and left >= 0 and top + wh <= h + 2 * pr and left + ww <= w + 2 * pc):
        raise ValueError(f"crop: window (top={top}, left={left}, height={wh}, width={ww}) does not fit in the "
                         f"{h + 2 * pr}x{w + 2 * pc} optical image (scene {h}x{w} padded by {pr}, {pc})")
    mr, mc = max(margin[0], 0), max(margin[1], 0)
    r0, c0 = top - pr - mr, left - pc - mc  # source window in scene coordinates
    buf = extend(x, (r0, r0 + wh + 2 * mr), (c0, c0 + ww + 2 * mc), pad_mode)
    my, mx = next_fast_size(wh + 2 * mr), next_fast_size(ww + 2 * mc)
    if (my, mx) != tuple(buf.shape[-2:]):  # (a no-op F.pad still copies the buffer)
        buf = torch.nn.functional.pad(buf, (0, mx - buf.shape[-1], 0, my - buf.shape[-2]))
    return buf, (pr, pc), (mr, mc, wh, ww)


def fft_frequencies(my: int, mx: int, dx: torch.Tensor, *, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """``(fy [B, My], fx [B, Mx // 2 + 1])`` in cycles/m: the rFFT grid of an ``My x Mx`` buffer of spacing ``dx``."""
    d = dx.to(dtype).reshape(-1, 1)
    fy = torch.fft.fftfreq(my, device=device, dtype=dtype)[None, :] / d
    fx = torch.fft.rfftfreq(mx, device=device, dtype=dtype)[None, :] / d
    return fy, fx


def blur_fft(x: torch.Tensor, otf_fn, dx: torch.Tensor, margin: tuple[int, int], pad_mode="zero",
             window: tuple[int, int, int, int] | None = None) -> tuple[torch.Tensor, tuple[int, int]]:
    """Blur ``x [B, L, H, W]`` by the OTF; see the module docstring.

    Args:
        x: image ``(B, L, H, W)``.
        otf_fn: callback giving the OTF on the FFT frequencies (cycles/m).
        dx: sample spacing ``(B,)`` (m).
        margin: ``(rows, cols)``: how far (samples) the PSF reaches, at the optics' tolerance.
        pad_mode: ``'zero'``, ``'mean'``, ``'edge'`` or a number.
        window: ``(top, left, height, width)`` in full-output samples, or None for the full output.

    Returns:
        ``(out, (pad_rows, pad_cols))``: the full padded output ``(B, L, H + 2 pr, W + 2 pc)`` (or the window)
        and the per-side padding of the full output.
    """
    buf, pad, (r0, c0, oh, ow) = fft_buffer(x, margin, pad_mode, window)
    out = _convolve(buf, otf_fn, dx)
    if (r0, c0, oh, ow) == (0, 0, *out.shape[-2:]):
        return out, pad
    return out[..., r0:r0 + oh, c0:c0 + ow], pad


def convolve_psf(x: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """Convolve maps ``(C, H, W)`` with a centred, odd-sized sampled PSF ``(S, S)`` (same sample spacing), borders
    extended by reflection (replication when the image is smaller than the PSF radius), in the Fourier domain.

    Linear convolution of a sampled image with a sampled PSF (Goodman, Introduction to Fourier Optics, ch. 6); used
    to defocus scene layers (:meth:`isettorch.optics.WavefrontOptics.defocus_maps`). A non-negative PSF on
    non-negative maps gives a non-negative result: the FFT's round-off (~1e-7 of the peak) is clamped at 0.

    Example:
        >>> x = torch.zeros(1, 9, 9); x[0, 4, 4] = 1.0
        >>> psf = torch.tensor([[0.0, 0.1, 0.0], [0.1, 0.6, 0.1], [0.0, 0.1, 0.0]])
        >>> bool(torch.allclose(convolve_psf(x, psf)[0, 3:6, 3:6], psf, atol=1e-6))
        True
    """
    if x.dim() != 3 or psf.dim() != 2 or psf.shape[0] != psf.shape[1] or psf.shape[0] % 2 == 0:
        raise ValueError(f"convolve_psf: expected x (C, H, W) and an odd square psf (S, S), got {tuple(x.shape)} "
                         f"and {tuple(psf.shape)}")
    r = psf.shape[-1] // 2
    mode = "reflect" if min(x.shape[-2:]) > r else "replicate"
    xp = F.pad(x[None], (r, r, r, r), mode=mode)[0]
    hp, wp = xp.shape[-2:]
    kernel = torch.zeros(hp, wp, dtype=xp.dtype, device=xp.device)
    kernel[:psf.shape[-2], :psf.shape[-1]] = psf.to(xp.dtype)
    kernel = torch.roll(kernel, (-r, -r), (0, 1))  # PSF centre at the origin
    out = torch.fft.irfft2(torch.fft.rfft2(xp) * torch.fft.rfft2(kernel), s=(hp, wp))
    return out[:, r:r + x.shape[-2], r:r + x.shape[-1]].clamp_min(0)
