"""Shift-invariant optics from a user-given PSF per wavelength (measured, or from a lens design program)."""

from __future__ import annotations

import torch
from torch import nn

from .._checks import as_tensor, check_nonnegative, check_wavelengths, tensor_version
from .base import ShiftInvariantLens, check_not_detached
from .psf_otf import otf_from_psf

__all__ = ["ShiftInvariantOptics"]


class ShiftInvariantOptics(ShiftInvariantLens):
    """Optics whose blur is a given PSF (the same over the field), with the thin-lens camera equation.

    The PSF is "resampled" without spatial interpolation: its OTF (the DTFT of the samples) is evaluated
    exactly at the optical image's FFT frequencies (:func:`~isettorch.optics.otf_from_psf`), band-limited to
    the PSF's own Nyquist frequency. Between the PSF's wavelengths the OTF is interpolated linearly; scene
    wavelengths outside ``psf_wavelengths_nm`` raise an error. A band-limited blur rings where the image is sampled
    finer than the PSF or the PSF is narrower than an image sample: the irradiance can go negative beside a sharp
    point (a PSF of 2 um samples on a 0.5 um grid: -6.1 % of the peak; a sub-sample PSF -2.6 %, as the diffraction-
    limited optics and ISETCam's OTF blur do), and is not clipped. Sample the PSF at least as finely as the image.

    Args:
        psf: ``(K, K')`` (one PSF for all wavelengths) or ``(Lp, K, K')``, non-negative; the origin (optical axis)
            is sample ``(K // 2, K' // 2)``. Each PSF is normalised to sum 1.
        psf_spacing_m: sample pitch of the PSF on the image plane (m), scalar or ``(Lp,)``.
        psf_wavelengths_nm: ``(Lp,)`` wavelengths of the PSFs (needed when Lp > 1).
        f_number, focal_length_m: for the camera equation and the geometry.
        learn_psf: make the PSF a trainable ``nn.Parameter``. Its OTF is cached per PSF version: optimiser steps,
            in-place edits under ``torch.no_grad()``, ``copy_`` and ``load_state_dict`` are seen; an edit through
            ``psf.data[...]`` is not (``.data`` bypasses the version counter): edit ``psf`` itself.
        Other arguments: see :class:`~isettorch.optics.base.ShiftInvariantLens`. The padding margin is half the
        PSF's extent, so the convolution is exactly linear.

    Example:
        >>> g = torch.exp(-(torch.arange(-8., 9.)[:, None] ** 2 + torch.arange(-8., 9.) ** 2) / 8)
        >>> optics = ShiftInvariantOptics(g, psf_spacing_m=1e-6, f_number=2.8, focal_length_m=5e-3)
    """

    def __init__(self, psf, psf_spacing_m, psf_wavelengths_nm=None, f_number=4.0, focal_length_m=3.862755099e-3,
                 *, learn_psf: bool = False, dtype=torch.float64, **kwargs) -> None:
        super().__init__(f_number, focal_length_m, dtype=dtype, **kwargs)
        if not learn_psf:
            check_not_detached(psf, "psf", "pass learn_psf=True (the module's own parameter)")
        check_not_detached(psf_spacing_m, "psf_spacing_m", "the PSF's sample spacing is a fixed property here")
        p = as_tensor(psf, "psf", dtype=dtype).detach().clone()
        if p.dim() == 2:
            p = p.unsqueeze(0)
        if p.dim() != 3 or min(p.shape[-2:]) < 1:
            raise ValueError(f"psf: expected a tensor of shape (K, K') or (Lp, K, K'), got {tuple(p.shape)}")
        check_nonnegative(p, "psf")
        if bool((p.sum(dim=(-2, -1)) <= 0).any()):
            raise ValueError("psf: every PSF must have a positive sum")
        self.psf = nn.Parameter(p, requires_grad=learn_psf)
        sp = as_tensor(psf_spacing_m, "psf_spacing_m", dtype=dtype).detach().clone().reshape(-1)
        if sp.numel() not in (1, p.shape[0]) or not torch.isfinite(sp).all() or (sp <= 0).any():
            raise ValueError(f"psf_spacing_m: expected 1 or {p.shape[0]} positive spacings, got {sp.tolist()}")
        self.register_buffer("psf_spacing_m", sp.expand(p.shape[0]).clone())
        if psf_wavelengths_nm is None:
            if p.shape[0] > 1:
                raise ValueError(f"psf_wavelengths_nm: required for {p.shape[0]} PSFs")
            self.psf_wavelengths_nm = None
        else:
            w = check_wavelengths(as_tensor(psf_wavelengths_nm, "psf_wavelengths_nm", dtype=dtype),
                                  "psf_wavelengths_nm")
            if w.numel() != p.shape[0]:
                raise ValueError(f"psf_wavelengths_nm: expected {p.shape[0]} wavelengths (one per PSF), got "
                                 f"{w.numel()}")
            self.register_buffer("psf_wavelengths_nm", w)

    def _otf_key(self) -> tuple:
        # the spacing and wavelengths too: changing psf_spacing_m kept the first OTF (a 2x wider PSF blurred as before)
        return (id(self.psf), tensor_version(self.psf), tuple(self.psf_spacing_m.tolist()),
                None if self.psf_wavelengths_nm is None else tuple(self.psf_wavelengths_nm.tolist()))

    def _weights(self, wavelengths_nm: torch.Tensor) -> torch.Tensor:
        """Linear interpolation weights ``[L, Lp]`` from the PSF wavelengths to ``wavelengths_nm``."""
        lp = self.psf.shape[0]
        w = wavelengths_nm.to(self.psf.dtype)
        if self.psf_wavelengths_nm is None or lp == 1:
            if self.psf_wavelengths_nm is not None and not bool((w == self.psf_wavelengths_nm[0]).all()):
                raise ValueError(f"wavelengths_nm: the single PSF is at {self.psf_wavelengths_nm.item()} nm, the "
                                 f"scene has {w.tolist()}; give psf_wavelengths_nm=None to use it for all")
            return torch.ones(w.numel(), 1, dtype=w.dtype, device=w.device)
        src = self.psf_wavelengths_nm.to(w.device)
        if bool((w < src[0]).any() or (w > src[-1]).any()):
            raise ValueError(f"wavelengths_nm: scene wavelengths {w.min().item():g}..{w.max().item():g} nm exceed the "
                             f"PSF range {src[0].item():g}..{src[-1].item():g} nm")
        idx = (torch.searchsorted(src, w, right=True) - 1).clamp(0, lp - 2)
        t = (w - src[idx]) / (src[idx + 1] - src[idx])
        out = torch.zeros(w.numel(), lp, dtype=w.dtype, device=w.device)
        out[torch.arange(w.numel()), idx] = 1 - t
        out[torch.arange(w.numel()), idx + 1] += t
        return out

    def otf(self, fy, fx, wavelengths_nm, f_number):
        wts = self._weights(wavelengths_nm)  # [L, Lp]
        used = wts.abs().sum(dim=0) > 0
        psf = self.psf[used].to(fy.dtype)
        sp = self.psf_spacing_m[used].to(fy.dtype)
        o = otf_from_psf(psf[None], sp[None], fy, fx)  # [B, Lu, My, Mx]
        return torch.einsum("lk,bkyx->blyx", wts[:, used].to(o.dtype), o)

    def psf_margin_m(self, wavelengths_nm, f_number):
        half = (torch.tensor(self.psf.shape[-2:], dtype=self.psf_spacing_m.dtype) // 2 + 1).max()
        m = (half * self.psf_spacing_m).max()
        return m.expand(f_number.shape[0]).to(f_number.dtype)

    def psf_core_m(self, wavelengths_nm, f_number):
        """The kernel's half size (:meth:`psf_margin_m`): all its light is within it."""
        return self.psf_margin_m(wavelengths_nm, f_number)
