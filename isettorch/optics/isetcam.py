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
from .._checks import as_tensor, batch_param, check_nonnegative, check_rank, check_wavelengths, round_half_away
from .geometry import cos4th_isetcam
from .optical_image import OpticalImage

__all__ = ["compute_oi", "unit_frequency_list", "dl_otf_isetcam", "pad_sizes", "mean_illuminance"]


def pad_sizes(height: int, width: int) -> tuple[int, int]:
    """ISETCam ``oiPad`` sizes: ``round([H W] / 8)`` per side, MATLAB rounding (halves away from zero)."""
    return round_half_away(height / 8), round_half_away(width / 8)


def unit_frequency_list(n: int, *, dtype=torch.float64, device=None) -> torch.Tensor:
    """ISETCam ``unitFrequencyList(n)``: ``(k - k_mid) / max|k - k_mid|``, k = 1..n, ``k_mid = n/2 + 1`` (even n)
    or ``(n + 1) / 2`` (odd n). For odd n this is the FFT grid stretched by ``n / (n - 1)``."""
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
    # oiGet 'vfov': 2 atand(0.5 * height_m / d), d = f (no depth map inside oiCompute)
    vfov = 2 * torch.rad2deg(torch.atan(0.5 * height * dx / f))
    fx = unit_frequency_list(width, device=dev)[None, :] * (width / 2) / hfov[:, None]
    fy = unit_frequency_list(height, device=dev)[None, :] * (height / 2) / vfov[:, None]
    # dlMTF: cutoff (D / d) / lambda cycles/m, times meters/deg = width / hfov, width = 2 d tand(hfov/2)
    width_m = 2 * f * torch.tan(torch.deg2rad(hfov) / 2)
    lam = wavelengths_nm.to(dt) * 1e-9
    fc = (1 / n)[:, None] / lam[None, :] * (width_m / hfov)[:, None]  # [B, L]
    rho = torch.sqrt(fy[:, :, None] ** 2 + fx[:, None, :] ** 2)  # [B, H, W]
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
    running sum over the column-major flattened image, as Octave's ``mean`` of single data (error up to 1e-3).
    """
    w = wavelengths_nm.to(torch.float64)
    bw = float(w[1] - w[0]) if w.numel() > 1 else 1.0
    h, c = constants.ISETCAM["h"], constants.ISETCAM["c"]
    e = photons.to(torch.float64) * (h * c) / (w[None, :, None, None] * 1e-9)
    lux = constants.KM_LM_PER_W * bw * torch.einsum("blhw,l->bhw", e, vlambda.to(torch.float64))
    if not float32_sequential:
        return lux.mean(dim=(1, 2))
    v = lux.to(torch.float32).transpose(1, 2).reshape(lux.shape[0], -1)  # column-major order
    return torch.cumsum(v, dim=1)[:, -1].double() / v.shape[1]


def compute_oi(scene_photons, wavelengths_nm, hfov_deg, distance_m, f_number, focal_length_m,
               transmittance=None, *, offaxis: str = "cos4th", dtype=None, return_details: bool = False):
    """ISETCam ``oiCompute`` for diffraction-limited optics, exactly as ISETCam returns it (padded OI).

    Args:
        scene_photons: radiance ``(L, H, W)`` or ``(B, L, H, W)``, photons/s/sr/m^2/nm.
        wavelengths_nm: ``(L,)``.
        hfov_deg, distance_m, f_number, focal_length_m: scalars or ``(B,)``.
        transmittance: lens transmittance on the scene wavelengths ``(L,)`` (default all ones).
        offaxis: ``'cos4th'`` (ISETCam's default, ``cos4th.m``) or ``'skip'``.
        dtype: dtype of the result (default: the photons' dtype). The arithmetic runs in float64.
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
    out_dtype = dtype or (p.dtype if p.is_floating_point() else torch.get_default_dtype())
    check_nonnegative(p.detach(), "scene_photons")
    dt, dev = torch.float64, p.device
    p = p.to(dt)
    b, nl, h, w = p.shape
    wave = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm", dtype=dt, device=dev))
    if wave.numel() != nl:
        raise ValueError(f"wavelengths_nm: expected {nl} wavelengths to match scene_photons, got {wave.numel()}")
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
    check_nonnegative(t, "transmittance")
    if offaxis not in ("cos4th", "skip"):
        raise ValueError(f"offaxis: expected 'cos4th' or 'skip', got {offaxis!r}")

    # oiCalculateIrradiance: thin-lens magnification at the scene distance
    d_img = 1 / (1 / f - 1 / dist)
    mag = -d_img / dist
    k = math.pi / (1 + 4 * n**2 * (1 + mag.abs()) ** 2)
    irr = k[:, None, None, None] * p * t[None, :, None, None]

    # geometry inside oiCompute: focal-plane distance f (no depth map yet)
    dx_c = 2 * f * torch.tan(torch.deg2rad(hfov) / 2) / w
    cos4 = None
    if offaxis == "cos4th":
        # oiGet 'spatialsupport': linspace(-n dx/2 + dx/2, n dx/2 - dx/2, n) on the unpadded grid
        ys = (torch.arange(h, dtype=dt, device=dev) - (h - 1) / 2)[None, :] * dx_c[:, None]
        xs = (torch.arange(w, dtype=dt, device=dev) - (w - 1) / 2)[None, :] * dx_c[:, None]
        # opticsGet 'magnification' without a selected scene is 0 (FORMAT.md 4.3)
        cos4 = cos4th_isetcam(ys, xs, f, n, 0.0)
        irr = irr * cos4

    # oiPad: round(size/8) per side, value max(photons) * 1e-9
    pr, pc = pad_sizes(h, w)
    h2, w2 = h + 2 * pr, w + 2 * pc
    pad_val = irr.flatten(1).amax(dim=1) * 1e-9
    padded = pad_val[:, None, None, None].expand(b, nl, h2, w2).clone()
    padded[:, :, pr:pr + h, pc:pc + w] = irr
    hfov_pad = 2 * torch.rad2deg(torch.atan((w2 / w) * torch.tan(torch.deg2rad(hfov) / 2)))

    otf, fx, fy = dl_otf_isetcam(wave, n, f, hfov_pad, dx_c, h2, w2)
    out = torch.fft.ifft2(otf * torch.fft.fft2(padded)).abs()

    # the returned oi has the scene depth map: focal-plane distance = thin-lens image distance
    spacing = 2 * d_img * torch.tan(torch.deg2rad(hfov_pad) / 2) / w2
    oi = OpticalImage(out.to(out_dtype), wave.to(out_dtype), name="isetcam diffraction limited",
                      sample_spacing_m=spacing, hfov_deg=hfov_pad, focal_length_m=f, f_number=n,
                      image_distance_m=d_img, pad_rows=pr, pad_cols=pc, validate=False)
    if not return_details:
        return oi
    details = {
        "cos4th_factor": None if cos4 is None else cos4[:, 0],
        "otf": otf, "fx_cpd": fx, "fy_cpd": fy,
        "sample_spacing_during_compute_m": dx_c, "focal_plane_distance_during_compute_m": f,
        "hfov_pad_deg": hfov_pad, "vfov_pad_deg": 2 * torch.rad2deg(torch.atan(0.5 * h2 * dx_c / f)),
        "pad_value": pad_val, "magnification": mag,
    }
    return oi, details
