"""ISETCam-compatible diffraction-limited optical image (``oiCompute`` with ``oiCreate('diffraction limited')``).

This reproduces, quirks included, what ISETCam (commit 3b10ec1) returns, as pinned down in
``isetcam-parity/FORMAT.md`` sections 4.1-4.4 and 4.7:

* irradiance ``pi / (1 + 4 N^2 (1 + |m|)^2) L T`` with the thin-lens ``m`` at the scene distance
  (``oiCalculateIrradiance``);
* ``cos4th.m`` fall-off on the **unpadded** grid, with image distance ``f`` and ``m = 0``;
* padding ``round(size / 8)`` per side with the value ``max(photons) * 1e-9`` (``oiPad``);
* the diffraction-limited OTF (``dlMTF``/``dlCore``) on ISETCam's cycles/deg grid (``unitFrequencyList``,
  stretched by ``n / (n - 1)`` on odd axes; ``fy`` from the vertical FOV), applied as
  ``abs(ifft2(OTF * fft2(img)))`` on the padded image (a circular convolution);
* inside the computation the focal-plane distance is ``f``; the returned OI's sample spacing uses the
  thin-lens image distance ``1 / (1/f - 1/d)`` (0.32 % larger at f = 3.86 mm, d = 1.2 m), because the
  returned oi carries the scene's depth map. ``OpticalImage.sample_spacing_m`` is that returned value,
  the one the sensor must use.

The physically sound :class:`~isettorch.optics.DiffractionLimitedOptics` default differs from this
(thin-lens geometry throughout, cos^4 at the image distance, textbook FFT grid, padding only as wide as
the PSF, no ``abs``); see its docstring for the measured difference.
"""

from __future__ import annotations

import math

import torch

from .. import constants
from .._autograd import records_grad, safe_sqrt
from .._cache import BoundedCache
from .._checks import (
    as_tensor,
    batch_param,
    check_finite,
    check_float_dtype,
    check_rank,
    check_wavelengths,
    round_half_away,
)
from .base import check_transmittance
from .geometry import cos4th_isetcam
from .optical_image import FourierFactors, OpticalImage

__all__ = ["compute_oi", "compute_oi_factored", "IsetcamFourierFactors", "compute_oi_scene", "unit_frequency_list",
           "dl_otf_isetcam",
           "pad_sizes", "mean_illuminance"]


def pad_sizes(height: int, width: int) -> tuple[int, int]:
    """ISETCam ``oiPad`` sizes: ``round([H W] / 8)`` per side, MATLAB rounding (halves away from zero)."""
    return round_half_away(height / 8), round_half_away(width / 8)


def unit_frequency_list(n: int, *, dtype=torch.float64, device=None) -> torch.Tensor:
    """ISETCam ``unitFrequencyList(n)``: ``(k - k_mid) / max|k - k_mid|``, k = 1..n, ``k_mid = n/2 + 1`` (even n)
    or ``(n + 1) / 2`` (odd n). For odd n this is the FFT grid stretched by ``n / (n - 1)``."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:  # (0 failed in max() of an empty tensor)
        raise ValueError(f"n: expected a whole number of samples >= 1, got {n!r}")
    k = torch.arange(1, n + 1, dtype=dtype, device=device)
    mid = n / 2 + 1 if n % 2 == 0 else (n + 1) / 2
    c = k - mid
    return c / c.abs().max() if n > 1 else c


def _ifftshift_len(n: int) -> int:
    return -(n // 2)


def dl_otf_isetcam(wavelengths_nm: torch.Tensor, f_number: torch.Tensor, focal_length_m: torch.Tensor,
                   hfov_deg: torch.Tensor, dx_m: torch.Tensor, height: int, width: int,
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """ISETCam's diffraction-limited OTF for a **padded** image of ``height x width`` samples (``dlMTF``).

    Args:
        wavelengths_nm: ``[L]``. f_number, focal_length_m: ``[B]``.
        hfov_deg: the padded horizontal FOV ``[B]``. dx_m: sample spacing used inside ``oiCompute`` ``[B]``.

    Returns:
        ``otf [B, L, H, W]`` (DC at ``[0, 0]``, ``ifftshift``-ed), and the centred axes ``fx [B, W]``,
        ``fy [B, H]`` in cycles/deg.
    """
    dt = torch.float64
    dev = wavelengths_nm.device
    n = f_number.to(dt)
    f = focal_length_m.to(dt)
    hfov = hfov_deg.to(dt)
    dx = dx_m.to(dt)
    # as dl_otf: f/0 gave an OTF of 1 everywhere, a negative f-number or wavelength values above 1, a NaN wavelength 0
    for name, v in (("wavelengths_nm", wavelengths_nm), ("f_number", n), ("focal_length_m", f), ("hfov_deg", hfov),
                    ("dx_m", dx)):
        d = torch.as_tensor(v).detach()
        if d.numel() == 0 or not bool(((d > 0) & torch.isfinite(d)).all()):
            raise ValueError(f"{name}: expected finite positive values, got {d.reshape(-1).tolist()}")
    for name, v in (("height", height), ("width", width)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name}: expected a whole number of samples >= 1, got {v!r}")
    # oiGet 'vfov': 2 atand(0.5 * height_m / d), d = f (no depth map inside oiCompute)
    vfov = 2 * torch.rad2deg(torch.atan(0.5 * height * dx / f))
    fx = unit_frequency_list(width, device=dev)[None, :] * (width / 2) / hfov[:, None]
    fy = unit_frequency_list(height, device=dev)[None, :] * (height / 2) / vfov[:, None]
    # dlMTF: cutoff (D / d) / lambda cycles/m, times meters/deg = width / hfov, width = 2 d tand(hfov/2)
    width_m = 2 * f * torch.tan(torch.deg2rad(hfov) / 2)
    lam = wavelengths_nm.to(dt) * 1e-9
    fc = (1 / n)[:, None] / lam[None, :] * (width_m / hfov)[:, None]  # [B, L]
    r2 = fy[:, :, None] ** 2 + fx[:, None, :] ** 2  # [B, H, W]
    # rho = sqrt(r2), with a finite gradient at DC: sqrt'(0) is infinite, times the 0 of d(r2) gave NaN for every
    # input the frequency grid depends on (hfov_deg, focal_length_m)
    rho = safe_sqrt(r2)
    s = rho[:, None] / fc[:, :, None, None]
    inside = s < 1
    sc = s.clamp(max=1.0)
    # dlCore: (2/pi)(acos s - s sqrt(1 - s^2)), 0 for s >= 1
    otf = torch.where(inside, (2 / math.pi) * (torch.acos(sc) - sc * torch.sqrt(1 - sc**2)), torch.zeros_like(sc))
    otf = torch.roll(otf, shifts=(_ifftshift_len(height), _ifftshift_len(width)), dims=(-2, -1))
    return otf, fx, fy


def mean_illuminance(photons: torch.Tensor, wavelengths_nm: torch.Tensor, vlambda: torch.Tensor,
                     *, float32_sequential: bool = False) -> torch.Tensor:
    """ISETCam's mean illuminance (lux) of OI photons ``[B, L, H, W]`` (FORMAT.md 4.1, 4.7).

    ``683 * binwidth * sum_l V(l) E(l)`` with ``E = photons h c / lambda`` (ISETCam ``vcConstants``), binwidth
    ``w[1] - w[0]`` (1 nm for a single wavelength). With ``float32_sequential`` the mean is a float32
    running sum over the column-major flattened image, as Octave's ``mean`` of single data (error up to 1e-3; no
    gradient).
    """
    w = wavelengths_nm.to(torch.float64)
    if vlambda.numel() != w.numel() or photons.dim() != 4 or photons.shape[1] != w.numel():
        raise ValueError(f"vlambda, photons: expected {w.numel()} values and [B, {w.numel()}, H, W] (one per "
                         f"wavelength), got {tuple(vlambda.shape)} and {tuple(photons.shape)}")
    bw = float(w[1] - w[0]) if w.numel() > 1 else 1.0
    h, c = constants.ISETCAM["h"], constants.ISETCAM["c"]
    e = photons.to(torch.float64) * (h * c) / (w[None, :, None, None] * 1e-9)
    lux = constants.KM_LM_PER_W * bw * torch.einsum("blhw,l->bhw", e, vlambda.to(torch.float64))
    if not float32_sequential:
        return lux.mean(dim=(1, 2))
    import numpy as np

    v = lux.detach().to(torch.float32).transpose(1, 2).reshape(lux.shape[0], -1).cpu().numpy()  # column-major order
    # a sequential float32 sum (NumPy's accumulate adds in the array's dtype, in order; torch's CPU cumsum adds float32
    # in double, which gave the exact mean: 1 + 10^6 x 1e-8 was 1.0099999, not float32's 1.0)
    total = np.add.accumulate(v, axis=1, dtype=np.float32)[:, -1]
    return torch.from_numpy(total.astype(np.float64)).to(lux.device) / v.shape[1]


# OTF half-spectra (rfft layout) and cos4th factors by geometry (wavelengths, f-numbers, focal lengths, FOVs,
# spacings, shape, dtype, device): a repeated call with the same optics and scene geometry reuses them
# (DESIGN principle 2: nothing recomputed that can be cached). Least recently used entries go first.
_CACHE = BoundedCache(16)


def _cached(key_of, make, *inputs) -> torch.Tensor:
    """``make()``, remembered under ``key_of()`` (least recently used out first) unless one of ``inputs`` records a
    gradient: a cached graph made the second backward through it raise."""
    if records_grad(*inputs):
        return make()
    key = key_of()
    hit = _CACHE.get(key)  # (a hit becomes the newest)
    if hit is not None:
        return hit
    _CACHE[key] = value = make()  # (bounded in entries and bytes)
    return value


def _half_otf(wave, n, f, hfov_pad, dx_c, h2: int, w2: int, dtype) -> torch.Tensor:
    """:func:`dl_otf_isetcam` restricted to the ``rfft2`` half plane ``[B, L, H2, W2 // 2 + 1]``, cached.

    The OTF is real and even on ISETCam's grid (a radial function sampled at ``±f``; ``unitFrequencyList`` is
    symmetric), so ``OTF * rfft2(img)`` is the half spectrum of ``OTF * fft2(img)`` and ``irfft2`` returns the
    real part of ``ifft2`` exactly."""
    return _cached(lambda: ("otf", tuple(wave.tolist()), tuple(n.tolist()), tuple(f.tolist()),
                            tuple(hfov_pad.tolist()), tuple(dx_c.tolist()), h2, w2, dtype, str(wave.device)),
                   lambda: dl_otf_isetcam(wave, n, f, hfov_pad, dx_c, h2, w2)[0][..., : w2 // 2 + 1].to(dtype)
                   .contiguous(), wave, n, f, hfov_pad, dx_c)


def _pad_spectrum(h: int, w: int, pr: int, pc: int, dtype, device) -> torch.Tensor:
    """``rfft2`` of the indicator of ISETCam's padding (1 outside the ``h x w`` scene, ``oiPad``) ``[1, 1, H2,
    W2 // 2 + 1]``, cached: one forward FFT fewer per factored call."""
    def make():
        ind = torch.ones(1, 1, h + 2 * pr, w + 2 * pc, dtype=dtype, device=device)
        ind[..., pr:pr + h, pc:pc + w] = 0
        return _rfft2(ind)

    return _cached(lambda: ("pad", h, w, pr, pc, dtype, str(device)), make)


def _use_scipy(x: torch.Tensor) -> bool:
    """SciPy's pocketfft for CPU tensors that need no gradient: 2-4x faster than torch's CPU ``irfft2`` on
    640^2 x 31 (``benchmarks/RESULTS.md``); the same transform to float rounding. Gradients take torch's."""
    return x.device.type == "cpu" and not records_grad(x)


def _rfft2(x: torch.Tensor) -> torch.Tensor:
    if _use_scipy(x):
        import scipy.fft

        return torch.from_numpy(scipy.fft.rfft2(x.numpy(), workers=torch.get_num_threads()))
    return torch.fft.rfft2(x)


def _irfft2(x: torch.Tensor, s) -> torch.Tensor:
    if _use_scipy(x):
        import scipy.fft

        return torch.from_numpy(scipy.fft.irfft2(x.numpy(), s=s, workers=torch.get_num_threads(),
                                                 overwrite_x=True))
    return torch.fft.irfft2(x, s=s)


def _work_dtype(compute_dtype, like: torch.Tensor) -> torch.dtype:
    if compute_dtype is None:
        return like.dtype if like.dtype in (torch.float32, torch.float64) else torch.float64
    return check_float_dtype(compute_dtype, "compute_dtype")


def _setup(b, nl, h, w, wavelengths_nm, hfov_deg, distance_m, f_number, focal_length_m, transmittance, offaxis,
           dev):
    """Validated geometry in float64 (FORMAT.md 4.2-4.4): everything except the image planes."""
    dt = torch.float64
    wave = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm", dtype=dt, device=dev))
    if wave.numel() != nl:
        raise ValueError(f"wavelengths_nm: expected {nl} wavelengths to match the radiance, got {wave.numel()}")
    kw = dict(dtype=dt, device=dev, positive=True)
    hfov = batch_param(hfov_deg, "hfov_deg", b, **kw)
    dist = batch_param(distance_m, "distance_m", b, **kw)
    n = batch_param(f_number, "f_number", b, **kw)
    f = batch_param(focal_length_m, "focal_length_m", b, **kw)
    if bool((hfov >= 180).any()):
        raise ValueError(f"hfov_deg: expected a field of view below 180 deg, got {hfov.tolist()}")
    if bool((dist <= f).any()):
        raise ValueError(f"distance_m: expected a scene beyond the focal length {f.tolist()}, got {dist.tolist()}")
    t = torch.ones(nl, dtype=dt, device=dev) if transmittance is None else as_tensor(
        transmittance, "transmittance", dtype=dt, device=dev).reshape(-1)
    if t.numel() != nl:
        raise ValueError(f"transmittance: expected {nl} values (one per wavelength), got {t.numel()}")
    check_transmittance(t)
    if offaxis not in ("cos4th", "skip"):
        raise ValueError(f"offaxis: expected 'cos4th' or 'skip', got {offaxis!r}")

    # oiCalculateIrradiance: pi / (1 + 4 N^2 (1 + |m|)^2), thin-lens magnification at the scene distance
    d_img = 1 / (1 / f - 1 / dist)
    mag = -d_img / dist
    k = math.pi / (1 + 4 * n**2 * (1 + mag.abs()) ** 2)
    # geometry inside oiCompute: focal-plane distance f (no depth map yet)
    dx_c = 2 * f * torch.tan(torch.deg2rad(hfov) / 2) / w
    cos4 = None
    if offaxis == "cos4th":
        # oiGet 'spatialsupport': linspace(-n dx/2 + dx/2, n dx/2 - dx/2, n) on the unpadded grid
        ys = (torch.arange(h, dtype=dt, device=dev) - (h - 1) / 2)[None, :] * dx_c[:, None]
        xs = (torch.arange(w, dtype=dt, device=dev) - (w - 1) / 2)[None, :] * dx_c[:, None]
        # opticsGet 'magnification' without a selected scene is 0 (FORMAT.md 4.3)
        cos4 = _cached(lambda: ("cos4", h, w, tuple(dx_c.tolist()), tuple(f.tolist()), tuple(n.tolist()), str(dev)),
                       lambda: cos4th_isetcam(ys, xs, f, n, 0.0), dx_c, f, n)  # [B, 1, H, W]
    # oiPad: round(size/8) per side
    pr, pc = pad_sizes(h, w)
    h2, w2 = h + 2 * pr, w + 2 * pc
    hfov_pad = 2 * torch.rad2deg(torch.atan((w2 / w) * torch.tan(torch.deg2rad(hfov) / 2)))
    return dict(wave=wave, n=n, f=f, t=t, k=k, d_img=d_img, mag=mag, dx_c=dx_c, cos4=cos4, pr=pr, pc=pc, h2=h2,
                w2=w2, hfov_pad=hfov_pad)


def _finish(spectrum, g, out_dtype, return_details, pad_val):
    """``abs(ifft2(OTF * fft2(padded)))`` from the padded image's half spectrum ``[B, L, H2, W2//2+1]``, and the
    returned OpticalImage (ISETCam ``oiApplyOTF``, FORMAT.md 4.4)."""
    h2, w2 = g["h2"], g["w2"]
    otf = _half_otf(g["wave"], g["n"], g["f"], g["hfov_pad"], g["dx_c"], h2, w2, spectrum.real.dtype)
    if spectrum.requires_grad or otf.requires_grad:
        spectrum = spectrum * otf
    else:
        torch.view_as_real(spectrum).mul_(otf[..., None])  # real x complex as a real product, in place
    out = _irfft2(spectrum, (h2, w2))
    out = out.abs() if out.requires_grad else out.abs_()
    # the returned oi has the scene depth map: focal-plane distance = thin-lens image distance
    spacing = 2 * g["d_img"] * torch.tan(torch.deg2rad(g["hfov_pad"]) / 2) / w2
    wave, n, f = g["wave"], g["n"], g["f"]
    oi = OpticalImage(out.to(out_dtype), wave.to(out_dtype), name="isetcam diffraction limited",
                      sample_spacing_m=spacing, hfov_deg=g["hfov_pad"], focal_length_m=f, f_number=n,
                      image_distance_m=g["d_img"], pad_rows=g["pr"], pad_cols=g["pc"], validate=False)
    if not return_details:
        return oi
    otf_full, fx, fy = dl_otf_isetcam(wave, n, f, g["hfov_pad"], g["dx_c"], h2, w2)
    details = {
        "cos4th_factor": None if g["cos4"] is None else g["cos4"][:, 0],
        "otf": otf_full, "fx_cpd": fx, "fy_cpd": fy,
        "sample_spacing_during_compute_m": g["dx_c"], "focal_plane_distance_during_compute_m": f,
        "hfov_pad_deg": g["hfov_pad"], "vfov_pad_deg": 2 * torch.rad2deg(torch.atan(0.5 * h2 * g["dx_c"] / f)),
        "pad_value": pad_val, "magnification": g["mag"],
    }
    return oi, details


def compute_oi(scene_photons, wavelengths_nm, hfov_deg, distance_m, f_number, focal_length_m,
               transmittance=None, *, offaxis: str = "cos4th", dtype=None, compute_dtype=None,
               return_details: bool = False):
    """ISETCam ``oiCompute`` for diffraction-limited optics, exactly as ISETCam returns it (padded OI).

    Args:
        scene_photons: radiance ``(L, H, W)`` or ``(B, L, H, W)``, photons/s/sr/m^2/nm.
        wavelengths_nm: ``(L,)``.
        hfov_deg, distance_m, f_number, focal_length_m: scalars or ``(B,)``.
        transmittance: lens transmittance on the scene wavelengths ``(L,)`` (default all ones).
        offaxis: ``'cos4th'`` (ISETCam's default, ``cos4th.m``) or ``'skip'``.
        dtype: dtype of the result (default: the photons' dtype).
        compute_dtype: dtype of the image arithmetic and FFTs (default: the photons' dtype, float64 for
            non-float input). The geometry and the OTF are computed in float64 either way. float32 stays within
            2.6e-5 of float64 on the 512^2 x 31 sweep (``benchmarks/RESULTS.md``); ISETCam itself stores float32.
        return_details: also return a dict with the intermediate quantities (cos4th factor, OTF, ...).

    Returns:
        OpticalImage ``(B, L, H + 2 pr, W + 2 pc)`` whose ``sample_spacing_m`` is ISETCam's returned
        ``oi_sample_spacing_m`` (thin-lens image distance), ``hfov_deg`` the padded FOV, ``pad_rows/cols``
        the per-side padding and ``image_distance_m`` the thin-lens image distance.

    Example:
        >>> oi = compute_oi(torch.ones(31, 64, 96), torch.arange(400., 701., 10.), 10.0, 1.2, 4.0, 3.862755e-3)
        >>> oi.photons.shape, oi.pad_rows, oi.pad_cols
        (torch.Size([1, 31, 80, 120]), 8, 12)

    Reference: ISETCam ``oiCompute``, ``opticsDLCompute``, ``oiCalculateIrradiance``, ``cos4th``, ``oiPad``,
    ``opticsOTF``/``oiApplyOTF``, ``dlMTF``, ``dlCore``; FORMAT.md 4.2-4.4.
    """
    if not isinstance(scene_photons, torch.Tensor):
        scene_photons = torch.as_tensor(scene_photons)
    p = scene_photons.unsqueeze(0) if scene_photons.dim() == 3 else scene_photons
    check_rank(p, 4, "scene_photons", "(L, H, W) or (B, L, H, W)")
    if p.is_complex() or p.numel() == 0:  # (aminmax's error named no argument)
        raise ValueError(f"scene_photons: expected real radiance of at least one wavelength and sample, got "
                         f"{p.dtype} of shape {tuple(p.shape)}")
    # (an integer dtype returned -2147483648 for 4.8e13 photons, or 0 for 0.18)
    out_dtype = check_float_dtype(dtype) if dtype is not None else (
        p.dtype if p.is_floating_point() else torch.get_default_dtype())
    lo, hi = torch.aminmax(p.detach())  # one pass; NaN propagates to both
    if not (math.isfinite(float(lo)) and math.isfinite(float(hi))):
        check_finite(p.detach(), "scene_photons")  # names the count of NaN/Inf entries
    if float(lo) < 0:
        raise ValueError(f"scene_photons: expected non-negative values, minimum is {float(lo):.6g}")
    work = _work_dtype(compute_dtype, p)
    b, nl, h, w = p.shape
    g = _setup(b, nl, h, w, wavelengths_nm, hfov_deg, distance_m, f_number, focal_length_m, transmittance,
               offaxis, p.device)
    # irradiance = k T(l) L(l, x) cos4(x) (oiCalculateIrradiance x opticsCos4th), padded (oiPad)
    scale = (g["k"][:, None] * g["t"][None, :]).to(work)  # [B, L]
    pr, pc, h2, w2 = g["pr"], g["pc"], g["h2"], g["w2"]
    cos4 = None if g["cos4"] is None else g["cos4"].to(work)
    if records_grad(p, scale, cos4):  # differentiable (the photons or the optics): no in-place writes
        irr = p.to(work) * scale[:, :, None, None]
        irr = irr if cos4 is None else irr * cos4
        pad_val = irr.amax(dim=(1, 2, 3)) * 1e-9
        outside = torch.nn.functional.pad(torch.zeros(h, w, dtype=work, device=p.device), (pc, pc, pr, pr), value=1.0)
        padded = torch.nn.functional.pad(irr, (pc, pc, pr, pr)) + pad_val[:, None, None, None] * outside
    else:  # the irradiance written straight into the padded buffer
        padded = torch.empty(b, nl, h2, w2, dtype=work, device=p.device)
        inner = padded[:, :, pr:pr + h, pc:pc + w]
        torch.mul(p.to(work), scale[:, :, None, None], out=inner)
        if cos4 is not None:
            inner.mul_(cos4)
        # oiPad value: max(photons) * 1e-9 over all wavelengths
        pad_val = inner.amax(dim=(1, 2, 3)) * 1e-9
        if pr or pc:
            v = pad_val[:, None, None, None]
            padded[:, :, :pr] = v
            padded[:, :, pr + h:] = v
            padded[:, :, pr:pr + h, :pc] = v
            padded[:, :, pr:pr + h, pc + w:] = v
    spectrum = _rfft2(padded)
    del padded
    return _finish(spectrum, g, out_dtype, return_details, pad_val)


class IsetcamFourierFactors(FourierFactors):
    """:class:`~isettorch.optics.optical_image.FourierFactors` of ISETCam's padded OI (``window`` = the whole
    padded buffer): :meth:`dense` is ``abs(ifft2(OTF * fft2(padded)))`` as ``oiApplyOTF`` returns it (FORMAT.md
    4.4); :meth:`project` (the sensor's K planes) is the projection of the blurred irradiance **before** the
    ``abs``. The two agree exactly wherever the blurred irradiance is non-negative at every wavelength (ISETCam's
    ``abs`` is then the identity). The irradiance is non-negative, so only the negative lobes of the PSF of
    ISETCam's truncated OTF (down to -1.8 % of its peak at 512^2, f/4) can make it negative, next to a dark region
    whose level is below the lobe times its bright neighbour. Measured: no negative value on the 512^2 sweep
    (minimum 4e-4 of the max, pad included) nor on the Macbeth parity case (2e-4); the tests check it. A scene
    with exact zeros beside bright areas may differ there: pass it dense (or read ``.photons``)."""

    @classmethod
    def _of(cls, f: FourierFactors) -> IsetcamFourierFactors:
        out = cls.__new__(cls)
        out.__dict__.update(f.__dict__)
        return out

    def dense(self) -> torch.Tensor:
        out = super().dense()
        return out.abs() if out.requires_grad else out.abs_()

    def select(self, index) -> IsetcamFourierFactors:
        return self._of(super().select(index))

    def scale(self, k: torch.Tensor) -> IsetcamFourierFactors:
        return self._of(super().scale(k))

    def crop(self, top: int, left: int, height: int, width: int) -> IsetcamFourierFactors:
        return self._of(super().crop(top, left, height, width))

    def to(self, device=None, dtype=None) -> IsetcamFourierFactors:
        return self._of(super().to(device, dtype))

    def detach(self) -> IsetcamFourierFactors:
        return self._of(super().detach())


def _lazy_oi(spec, coef, g, out_dtype) -> OpticalImage:
    """The OI of :func:`compute_oi_factored` (``lazy=True``) kept as its map spectra ``spec [B, J + 1, H2, W2']``,
    coefficients ``coef [B, J + 1, L]`` and the cached OTF half plane: no inverse FFT until asked."""
    h2, w2 = g["h2"], g["w2"]
    otf = _half_otf(g["wave"], g["n"], g["f"], g["hfov_pad"], g["dx_c"], h2, w2, coef.dtype)
    factors = IsetcamFourierFactors(spec, coef, otf, (h2, w2), (0, 0, h2, w2))
    if factors.dtype != out_dtype:
        factors = factors.to(dtype=out_dtype)
    spacing = 2 * g["d_img"] * torch.tan(torch.deg2rad(g["hfov_pad"]) / 2) / w2
    return OpticalImage(None, g["wave"].to(out_dtype), name="isetcam diffraction limited", factors=factors,
                        sample_spacing_m=spacing, hfov_deg=g["hfov_pad"], focal_length_m=g["f"], f_number=g["n"],
                        image_distance_m=g["d_img"], pad_rows=g["pr"], pad_cols=g["pc"], validate=False)


def compute_oi_factored(maps, spectra, wavelengths_nm, hfov_deg, distance_m, f_number, focal_length_m,
                        transmittance=None, *, offaxis: str = "cos4th", dtype=None, compute_dtype=None,
                        return_details: bool = False, lazy: bool = False):
    """:func:`compute_oi` of a factored radiance ``L(l, x) = sum_j maps_j(x) spectra_j(l)``: one FFT per map.

    Everything before the blur is linear in the radiance and the OTF acts per wavelength, so the padded
    irradiance's spectrum is ``sum_j S_j(l) rfft2(M_j) + c(l) rfft2(1_pad)``, with ``M_j`` the map times cos4
    (zero in the padding), ``S_j = k T spectra_j`` and the padding value ``c = max(irradiance) 1e-9`` carried as one
    more map (the indicator of the padding, ISETCam ``oiPad``). J + 1 forward FFTs instead of L; the L inverse
    FFTs and the ``abs`` are those of :func:`compute_oi`, and the result equals it to float rounding.

    Args:
        maps: ``(B, J, H, W)`` (or ``(J, H, W)``), spectra: ``(B, J, L)`` (or ``(J, L)``), in radiance units
            (photons/s/sr/m^2/nm) when multiplied; their product must be non-negative.
        lazy: return the OI in the Fourier domain (:class:`IsetcamFourierFactors`: the J + 1 forward FFTs only);
            the sensor then asks for its K projected planes (K inverse FFTs instead of L) and ``.photons`` builds
            the dense, ``abs``-ed cube of ``lazy=False`` on first read. Ignored with ``return_details``.
        the rest: as :func:`compute_oi`.
    """
    maps = torch.as_tensor(maps)
    spectra = torch.as_tensor(spectra)
    m = maps.unsqueeze(0) if maps.dim() == 3 else maps
    s = spectra.unsqueeze(0) if spectra.dim() == 2 else spectra
    check_rank(m, 4, "maps", "(J, H, W) or (B, J, H, W)")
    check_rank(s, 3, "spectra", "(J, L) or (B, J, L)")
    if s.shape[1] != m.shape[1] or s.shape[0] not in (1, m.shape[0]) or m.shape[0] not in (1, s.shape[0]):
        raise ValueError(f"spectra: expected (B, J, L) matching maps (B, J, H, W) = {tuple(m.shape)}, "
                         f"got {tuple(s.shape)}")
    for name, t in (("maps", m), ("spectra", s)):
        if t.is_complex() or t.numel() == 0:  # (an IndexError, or torch's NotImplementedError)
            raise ValueError(f"{name}: expected real values, at least one term, wavelength and sample, got {t.dtype} "
                             f"of shape {tuple(t.shape)}")
    check_finite(m.detach(), "maps")
    check_finite(s.detach(), "spectra")
    out_dtype = check_float_dtype(dtype) if dtype is not None else (
        m.dtype if m.is_floating_point() else torch.get_default_dtype())
    work = _work_dtype(compute_dtype, m)
    b = max(m.shape[0], s.shape[0])
    m, s = m.expand(b, *m.shape[1:]), s.expand(b, *s.shape[1:])
    nj, h, w = m.shape[1:]
    nl = s.shape[-1]
    g = _setup(b, nl, h, w, wavelengths_nm, hfov_deg, distance_m, f_number, focal_length_m, transmittance,
               offaxis, m.device)
    mw = m.to(work)
    if g["cos4"] is not None:
        mw = mw * g["cos4"].to(work)
    sw = s.to(work) * (g["k"][:, None] * g["t"][None, :]).to(work)[:, None, :]  # [B, J, L]
    # max over (x, l) of sum_j M_j(x) S_j(l); rank 1 with non-negative factors: max M x max S. Signed factors: the
    # product's minimum too (a radiance negative somewhere was let through by a check of the maximum, and the final
    # abs of oiCompute turned it into positive irradiance)
    signed = not (bool((mw >= 0).all()) and bool((sw >= 0).all()))
    if nj == 1 and not signed:
        peak = mw.flatten(1).amax(1) * sw.flatten(1).amax(1)
    elif not signed:
        peak = torch.stack([torch.einsum("jp,jl->pl", mw[i].flatten(1), sw[i]).amax() for i in range(b)])
    else:
        lo, peak = torch.stack([torch.stack(torch.aminmax(torch.einsum("jp,jl->pl", mw[i].flatten(1), sw[i])))
                                for i in range(b)]).unbind(1)
        # signed terms that cancel to 0 round to either side: a negative beyond the sum's rounding is refused
        scale = (mw.detach().abs().flatten(2).amax(-1) * sw.detach().abs().amax(-1)).sum(-1)
        if bool((lo < -64 * torch.finfo(work).eps * scale).any()):
            raise ValueError(f"maps, spectra: expected a non-negative radiance (sum_j maps_j spectra_j), minimum is "
                             f"{float(lo.min()):.6g}")
    pad_val = peak * 1e-9
    pr, pc, h2, w2 = g["pr"], g["pc"], g["h2"], g["w2"]
    planes = torch.zeros(b, nj, h2, w2, dtype=work, device=m.device)
    planes[:, :, pr:pr + h, pc:pc + w] = mw
    coef = torch.cat([sw, pad_val[:, None, None].expand(b, 1, nl)], dim=1)  # [B, J+1, L]
    f_pad = _pad_spectrum(h, w, pr, pc, work, m.device)  # the padding's indicator, cached by geometry
    f_maps = torch.cat([_rfft2(planes), f_pad.expand(b, 1, *f_pad.shape[-2:])], dim=1)  # [B, J+1, H2, W2//2+1]
    if lazy and not return_details:
        return _lazy_oi(f_maps, coef, g, out_dtype)
    if f_maps.requires_grad:  # differentiable: out of place
        spectrum = f_maps[:, :1] * coef[:, 0, :, None, None]
        for j in range(1, nj + 1):
            spectrum = spectrum + f_maps[:, j:j + 1] * coef[:, j, :, None, None]
        return _finish(spectrum, g, out_dtype, return_details, pad_val)
    # sum_j S_j(l) F_j + c F_pad as real arithmetic on (re, im) pairs, one pass per map over the L planes
    fr = torch.view_as_real(f_maps)  # [B, J+1, H2, W2', 2]
    pad_term = (fr[:, nj] * pad_val[:, None, None, None].to(work))[:, None]  # c F_pad, [B, 1, H2, W2', 2]
    out = torch.addcmul(pad_term, fr[:, :1], sw[:, 0, :, None, None, None])  # [B, L, H2, W2', 2]
    for j in range(1, nj):
        out.addcmul_(fr[:, j:j + 1], sw[:, j, :, None, None, None])
    return _finish(torch.view_as_complex(out), g, out_dtype, return_details, pad_val)


def compute_oi_scene(scene, f_number, focal_length_m, transmittance=None, *, offaxis: str = "cos4th", **kwargs):
    """:func:`compute_oi` of a Scene, or :func:`compute_oi_factored` when the scene is factored
    (``scene.is_factored``: radiance ``sum_j maps [B, J, H, W] x spectra [B, J, L]``): one call for both forms,
    so a factored scene takes the J + 1 FFT path. ``kwargs`` as :func:`compute_oi` (``dtype``, ``compute_dtype``,
    ``return_details``), and ``lazy`` (:func:`compute_oi_factored`; a dense scene's OI is dense)."""
    args = (scene.wavelengths_nm, scene.hfov_deg, scene.distance_m, f_number, focal_length_m, transmittance)
    lazy = kwargs.pop("lazy", False)
    # (a Scene whose dense cube was changed in place is that cube; a duck-typed scene says is_factored)
    if getattr(scene, "factors_hold_image", getattr(scene, "is_factored", False)):
        return compute_oi_factored(scene.maps, scene.spectra, *args, offaxis=offaxis, lazy=lazy, **kwargs)
    return compute_oi(scene.photons, *args, offaxis=offaxis, **kwargs)
