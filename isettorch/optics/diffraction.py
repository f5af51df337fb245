"""Diffraction-limited optics: the incoherent OTF of an aberration-free circular pupil."""

from __future__ import annotations

import math

import torch

from .._autograd import records_grad, safe_sqrt
from .base import ShiftInvariantLens, _check_crop
from .isetcam import compute_oi_scene

__all__ = ["dl_otf", "dl_mtf_1d", "DiffractionLimitedOptics"]

#: without a gradient, :func:`dl_otf` evaluates grids larger than this (elements per wavelength x batch) a few
#: wavelengths at a time
_OTF_CHUNK_ELEMENTS = 1 << 22


def dl_mtf_1d(s: torch.Tensor) -> torch.Tensor:
    """Diffraction-limited MTF of a circular pupil at normalised frequency ``s = f / f_c`` (``f_c = 1 / (lambda N)``):
    ``(2/pi)(acos s - s sqrt(1 - s^2))`` for ``s < 1``, else 0 (Goodman, Introduction to Fourier Optics, 6.31;
    ISETCam ``dlCore``), even in ``s`` (a negative frequency is its mirror; it gave values above 1) and NaN where ``s``
    is NaN (it gave 0). Gradients are finite everywhere (the branch for ``|s| >= 1`` is never differentiated).
    """
    a = s.abs()
    outside = a >= 1  # (False for NaN, which then passes through acos: NaN out)
    ss = torch.where(outside, torch.zeros_like(a), a)
    val = (2 / math.pi) * (torch.acos(ss) - ss * torch.sqrt(1 - ss * ss))
    return torch.where(outside, torch.zeros_like(val), val)


def dl_otf(fy: torch.Tensor, fx: torch.Tensor, wavelengths_nm: torch.Tensor, f_number: torch.Tensor,
           ) -> torch.Tensor:
    """Diffraction-limited OTF ``[B, L, My, Mx]`` at frequencies ``fy [B, My]``, ``fx [B, Mx]`` (cycles/m).

    Cutoff ``1 / (lambda N)`` (Goodman 6.31). ``f_number`` is ``[B]`` (> 0), ``wavelengths_nm`` ``[L]``.
    """
    # N <= 0 has no OTF (it gave values above 1, or 1 everywhere); a NaN wavelength gave an OTF of 0, a negative one
    # above 1: one host read for both
    n_ok = (f_number.detach() > 0).all()
    w = torch.as_tensor(wavelengths_nm).detach()
    w_ok = ((w > 0) & torch.isfinite(w)).all()
    if not bool(n_ok.to(w_ok.device) & w_ok):
        if not bool(n_ok):
            raise ValueError(f"f_number: expected positive values, got {f_number.detach().reshape(-1).tolist()}")
        raise ValueError(f"wavelengths_nm: expected finite positive wavelengths, got {w.reshape(-1).tolist()}")
    r2 = fy[:, :, None] ** 2 + fx[:, None, :] ** 2  # [B, My, Mx]
    # sqrt's derivative at DC is 0/0: NaN through the spacing (hfov, distance) even there
    rho = safe_sqrt(r2) if records_grad(r2) else torch.sqrt(r2)
    lam_n = wavelengths_nm.to(rho.dtype)[None, :] * 1e-9 * f_number.to(rho.dtype).reshape(-1, 1)  # [B, L]
    step = max(1, _OTF_CHUNK_ELEMENTS // rho.numel())
    if step >= lam_n.shape[1] or records_grad(rho, lam_n):
        return dl_mtf_1d(rho[:, None] * lam_n[:, :, None, None])
    # a large grid without a gradient: a few wavelengths at a time into the result (the same formula element by
    # element; the vectorised acos / sqrt may round a few elements in the last bit differently where a chunk's
    # boundary moves them between its SIMD and remainder loops), so dl_mtf_1d's temporaries, about eight of the
    # result's size, exist for those wavelengths only
    # (a 6 MP photograph's padded grid at 31 wavelengths: 0.4 GB of OTF, a 3 GB peak when evaluated at once)
    out = rho.new_empty(rho.shape[0], lam_n.shape[1], *rho.shape[1:])
    for lo in range(0, lam_n.shape[1], step):
        out[:, lo:lo + step] = dl_mtf_1d(rho[:, None] * lam_n[:, lo:lo + step, None, None])
    return out


class DiffractionLimitedOptics(ShiftInvariantLens):
    """Aberration-free lens: camera equation, relative illumination and the diffraction-limited OTF.

    Args:
        f_number: f-number (scalar or ``[B]``; trainable with ``learn_f_number=True``).
        focal_length_m: focal length (m), scalar or ``[B]``. Default ISETCam's 3.862755 mm.
        pad_mode: ``'zero'`` (default), ``'mean'``, ``'edge'``, a number, or ``'isetcam'``: ISETCam's
            ``oiCompute`` exactly (:func:`isettorch.optics.isetcam.compute_oi`: ``round(size/8)`` padding with
            ``max * 1e-9``, its grids, ``abs(ifft2)``, ISETCam's ``cos4th.m`` with ``d = f, m = 0`` for any
            ``relative_illumination`` but None; ``crop`` then slices; ``camera_equation``, ``margin`` and the
            tolerances, which ISETCam fixes, are refused). A factored
            scene's OI is returned in the Fourier domain (:class:`~isettorch.optics.isetcam.IsetcamFourierFactors`):
            the sensor projects it on its QE (K inverse FFTs, not L); ``.photons`` gives the dense cube.
        Other arguments: see :class:`~isettorch.optics.base.ShiftInvariantLens`.

    The default (physically sound) mode uses the thin-lens image distance everywhere (sample spacing, cos^4, and the
    diffraction cutoff ``1 / (lambda N d_i / f)``, the working f-number: Goodman 6.3.2; ISETCam's uses ``N``, 0.32 %
    apart on its Macbeth case), the textbook FFT frequency grid, no ``abs``, and pads by ``2 lambda_max N / (pi^3
    tol)`` (the distance beyond which the diffraction line-spread function holds less than ``tol`` of its energy;
    its tail is ``2 lambda N / (pi^3 a)``, from the MTF's slope ``-4/pi`` at 0). Measured against ISETCam on the
    Macbeth case (64x96x31, f/4, f = 3.86 mm, 1.2 m; ``tests/optics/test_isetcam_parity.py``): both give the same
    sample spacing (ISETCam computes cos4th and the OTF with ``d = f`` but returns the thin-lens spacing, 0.32 %
    larger, which is the one used here throughout); over the scene region, at pixels above 1 % of the max, the
    irradiance differs by median 0.081 %, max 1.17 % (0.082 % and 1.13 % with ISETCam's cutoff, at N). The cos^4 law
    vs ISETCam's finite-aperture formula accounts for < 0.01 % of that; the rest is the blur near strong edges and
    the image border (ISETCam's circular convolution over a ``size/8`` pad, its grids and cutoff in cycles/deg,
    ``abs``).

    Example:
        >>> optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3)
        >>> oi = optics(scene)  # doctest: +SKIP

    Reference: Goodman, Introduction to Fourier Optics (3rd ed.), 6.3; ISETCam ``opticsDLCompute``.
    """

    def __init__(self, f_number=4.0, focal_length_m=3.862755099e-3, transmittance=None,
                 transmittance_wavelengths_nm=None, **kwargs) -> None:
        pad_mode = kwargs.get("pad_mode", "zero")
        self.isetcam = pad_mode == "isetcam"
        if self.isetcam:
            # ISETCam's oiCompute fixes the camera equation and the padding (round(size / 8)): an option that would
            # change them was silently ignored (camera_equation='paraxial' rendered as ISETCam's)
            ignored = [k for k in ("margin", "psf_tolerance", "max_margin_factor", "blur_skip_tolerance")
                       if k in kwargs]
            if kwargs.get("camera_equation", "isetcam") != "isetcam":
                ignored.insert(0, "camera_equation")
            if ignored:
                raise ValueError(f"{ignored[0]}: pad_mode='isetcam' is ISETCam's oiCompute, whose camera equation "
                                 f"and padding are fixed; leave {', '.join(ignored)} out (or use another pad_mode)")
            kwargs["pad_mode"] = "zero"
        super().__init__(f_number, focal_length_m, transmittance, transmittance_wavelengths_nm, **kwargs)

    otf_rows_independent = True  # the OTF of item b depends only on its frequencies and f-number
    blur_at_image_distance = True  # a pupil's diffraction: cutoff 1 / (lambda N (1 + |m|)) at a finite distance

    def otf(self, fy, fx, wavelengths_nm, f_number):
        return dl_otf(fy, fx, wavelengths_nm, f_number)

    def psf_margin_m(self, wavelengths_nm, f_number):
        # line-spread tail beyond a: 2 lambda N / (pi^3 a)  (asymptotic: the circular pupil's line-spread function
        # is H1(2v) / v^2, Struve's H1 -> 2 / pi far out (Marchand, JOSA 54(7), 915, 1964), the 1 / x^2 tail that the
        # MTF's slope -4/pi at 0 implies (Bracewell, The Fourier Transform and Its Applications, on asymptotic forms)
        lam = wavelengths_nm.max() * 1e-9
        return 2 * lam * f_number / (math.pi**3 * self.psf_tolerance)

    def blur_negligible(self, dx, wavelengths_nm, f_number):
        # max |1 - OTF| on the grid is at the corner frequency sqrt(2) / (2 dx); memoised per item on the plain
        # numbers (spacing, f-number): asked twice per camera call, by plan() and forward(), and repeated by a
        # dataset's few cameras (a stream shares one memo between its groups' optics, whose items mix them)
        dxs, ns = dx.detach().reshape(-1).tolist(), f_number.detach().reshape(-1).tolist()
        if len(dxs) != len(ns):  # one of them broadcasts
            if 1 not in (len(dxs), len(ns)):
                raise ValueError(f"dx, f_number: expected one value or one per item each, got {len(dxs)} and "
                                 f"{len(ns)}")
            dxs, ns = dxs * (len(ns) if len(dxs) == 1 else 1), ns * (len(dxs) if len(ns) == 1 else 1)
        lam_m = float(wavelengths_nm.max()) * 1e-9
        memo = self.__dict__.setdefault("_negligible_memo", {})
        hit = True
        for d, n in zip(dxs, ns):
            key = (d, lam_m, n, self.blur_skip_tolerance)
            item = memo.get(key)
            if item is None:
                s = torch.tensor((math.sqrt(2) / (2 * d)) * lam_m * n, dtype=torch.float64)
                item = bool(1 - dl_mtf_1d(s) <= self.blur_skip_tolerance)
                if len(memo) > 256:
                    memo.clear()
                memo[key] = item
            hit = hit and item
        return hit

    def plan(self, scene):
        if not self.isetcam:
            return super().plan(scene)
        h, w = scene.height, scene.width
        from .isetcam import pad_sizes

        pr, pc = pad_sizes(h, w)
        _, _, d_i, _ = self._geometry(scene)
        hfov_pad = 2 * torch.rad2deg(torch.atan((w + 2 * pc) / w * torch.tan(torch.deg2rad(scene.hfov_deg) / 2)))
        dx = 2 * d_i * torch.tan(torch.deg2rad(hfov_pad) / 2) / (w + 2 * pc)
        return {"full_shape": (h + 2 * pr, w + 2 * pc), "pad": (pr, pc), "sample_spacing_m": dx,
                "image_distance_m": d_i, "margin": max(pr, pc)}

    def forward(self, scene, crop=None):
        if not self.isetcam:
            return super().forward(scene, crop)
        b = scene.batch_size
        dt, dev = scene.dtype, scene.device
        t = self.transmittance_on(scene.wavelengths_nm)
        # a factored scene takes compute_oi_factored's J + 1 FFT path (never densified) and stays in the Fourier
        # domain (lazy): the sensor projects it on its K QE weightings (K inverse FFTs, not L)
        oi = compute_oi_scene(scene, self.batch_f_number(b, dt, dev), self.batch_focal_length(b, dt, dev), t,
                              offaxis="skip" if self.relative_illumination in (None, "none") else "cos4th",
                              lazy=True)
        if crop is not None:
            _check_crop(crop)
            full = (oi.height, oi.width)
            pad = (oi.pad_rows, oi.pad_cols)
            oi = oi.crop(*crop)
            oi.metadata = {"full_shape": full, "full_pad": pad, "window": (crop[0], crop[1])}
        return oi
