"""PSF -> OTF on another grid: the discrete-time Fourier transform of a sampled PSF, evaluated exactly at the
frequencies an optical image needs (no spatial interpolation of the PSF; differentiable in the PSF and its
sample spacing)."""

from __future__ import annotations

import math

import torch

__all__ = ["otf_from_psf"]


def otf_from_psf(psf: torch.Tensor, spacing_m: torch.Tensor, fy: torch.Tensor, fx: torch.Tensor,
                 band_limit: bool = True) -> torch.Tensor:
    """OTF ``[B, L, My, Mx]`` (complex) of PSFs ``psf [B|1, L, K, K']`` sampled at ``spacing_m [B|1, L]`` (m).

    The PSF's origin is sample ``(K // 2, K' // 2)`` (``fftshift`` layout); it is normalised to sum 1, so
    OTF(0) = 1. ``OTF(f) = sum_k psf[k] exp(-2 pi i f x_k)``, computed separably as ``E_y psf E_x^T``.
    With ``band_limit`` frequencies beyond the PSF's own Nyquist ``1 / (2 spacing)`` get 0 (the PSF is
    taken as band-limited, i.e. sinc-interpolated, rather than periodic in frequency).

    Args:
        fy: ``[B, My]``, fx: ``[B, Mx]`` frequencies in cycles/m.
    """
    k, kk = psf.shape[-2:]
    rdt = psf.dtype
    total = psf.sum(dim=(-2, -1), keepdim=True)
    # one host read: a PSF summing to 0 gave a NaN OTF, a spacing <= 0 an OTF of 0 at every frequency (the band
    # limit 1 / (2 spacing) below 0), DC included: a black image
    ok = torch.isfinite(total).all() & (total > 0).all()
    sp_ok = (torch.isfinite(spacing_m) & (spacing_m > 0)).all()
    if not bool(ok & sp_ok.to(ok.device)):
        if not bool(sp_ok):
            raise ValueError(f"spacing_m: expected finite sample spacings > 0 (m), got "
                             f"{spacing_m.detach().reshape(-1)[:8].tolist()}")
        raise ValueError("psf: expected finite PSFs with a positive sum in every plane (the OTF is the PSF "
                         "normalised to sum 1)")
    psf = psf / total
    ds = spacing_m.to(rdt)[..., None, None]  # [B, L, 1, 1]
    yk = (torch.arange(k, dtype=rdt, device=psf.device) - k // 2)
    xk = (torch.arange(kk, dtype=rdt, device=psf.device) - kk // 2)
    fy4 = fy.to(rdt)[:, None, :, None]  # [B, 1, My, 1]
    fx4 = fx.to(rdt)[:, None, :, None]
    ey = torch.polar(torch.ones((), dtype=rdt, device=psf.device), -2 * math.pi * fy4 * yk * ds)  # [B, L, My, K]
    ex = torch.polar(torch.ones((), dtype=rdt, device=psf.device), -2 * math.pi * fx4 * xk * ds)  # [B, L, Mx, K']
    otf = ey @ psf.to(ey.dtype) @ ex.transpose(-2, -1)
    if band_limit:
        nyq = 1 / (2 * ds)
        inside = (fy4.abs() <= nyq) & (fx.to(rdt)[:, None, None, :].abs() <= nyq)
        otf = torch.where(inside, otf, torch.zeros((), dtype=otf.dtype, device=otf.device))
    return otf
