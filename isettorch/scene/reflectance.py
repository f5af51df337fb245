"""Scenes from reflectance maps (reflectance x illuminant) and from RGB images shown on a display."""

from __future__ import annotations

import torch

from .. import spectral
from .._checks import check_finite
from ._common import (
    DEFAULT_DISTANCE_M,
    DEFAULT_HFOV_DEG,
    DEFAULT_MEAN_LUMINANCE_CD_M2,
    check_float,
    finish,
    illuminant_energy,
    resolve_grid,
)
from .display import Display, _check_rgb, flat_screen_hfov_deg
from .scene import Scene

__all__ = ["reflectance_scene", "from_rgb"]


def reflectance_scene(reflectance: torch.Tensor, illuminant="D65", wavelengths=None, *,
                      mean_luminance_cd_m2=DEFAULT_MEAN_LUMINANCE_CD_M2, hfov_deg=DEFAULT_HFOV_DEG,
                      distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """Radiance = reflectance x illuminant (photons), for a spectral reflectance image.

    Args:
        reflectance: [B, L, H, W] or [L, H, W], non-negative (values above 1, e.g. fluorescence, are kept).
        illuminant: a name (:func:`isettorch.spectral.illuminant`), an energy SPD [L], or one per sample [B, L].
        wavelengths: the reflectance's grid [L] (nm); default 400:10:700, which then needs L = 31.

    Returns:
        Scene (B, L, H, W) with ``illuminant_photons``, so ``scene.reflectance()`` returns ``reflectance``.
        Differentiable with respect to ``reflectance`` (and a tensor illuminant).

    Example:
        >>> r = torch.full((31, 2, 2), 0.5)
        >>> bool(torch.allclose(reflectance_scene(r).reflectance(), r))
        True
    """
    if not isinstance(reflectance, torch.Tensor):
        raise TypeError(f"reflectance: expected a torch.Tensor [B, L, H, W], got {type(reflectance).__name__}")
    refl = reflectance.unsqueeze(0) if reflectance.dim() == 3 else reflectance
    if refl.dim() != 4:
        raise ValueError(f"reflectance: expected shape [B, L, H, W] or [L, H, W], got {tuple(reflectance.shape)}")
    if not refl.is_floating_point():
        refl = refl.to(torch.get_default_dtype())
    w = resolve_grid(wavelengths, dtype or refl.dtype, device or refl.device)
    if refl.shape[1] != w.numel():
        raise ValueError(f"reflectance: expected {w.numel()} wavelengths along dim 1 to match the grid "
                         f"({w[0].item():g}..{w[-1].item():g} nm), got shape {tuple(refl.shape)}; "
                         "pass wavelengths=")
    refl = refl.to(dtype=w.dtype, device=w.device)
    check_finite(refl.detach(), "reflectance")
    if (refl.detach() < 0).any():
        raise ValueError(f"reflectance: expected non-negative values, minimum is {refl.min().item():.6g}")
    b = refl.shape[0]
    if isinstance(illuminant, torch.Tensor) and illuminant.dim() == 2:
        if illuminant.shape[0] not in (1, b):
            raise ValueError(f"illuminant: expected [L], [1, L] or [{b}, L], got {tuple(illuminant.shape)}")
        ill_e = torch.stack([illuminant_energy(row, w, f"illuminant[{i}]") for i, row in enumerate(illuminant)])
    else:
        ill_e = illuminant_energy(illuminant, w)[None]
    ill_p = spectral.energy_to_photons(ill_e, w, dim=-1).expand(b, -1)
    photons = refl * ill_p[:, :, None, None]
    name = f"reflectance x {illuminant}" if isinstance(illuminant, str) else "reflectance scene"
    return finish(photons, w, hfov_deg=hfov_deg, distance_m=distance_m, mean_luminance_cd_m2=mean_luminance_cd_m2,
                  illuminant_photons=ill_p, name=name)


def from_rgb(rgb: torch.Tensor, display="lcd", wavelengths=None, *, dpi: float | None = None,
             viewing_distance_m: float | None = None, mean_luminance_cd_m2: float | None = None, dtype=None,
             device=None) -> Scene:
    """An RGB image shown on a display, as the spectral radiance the display emits.

    ``radiance = sum_k eotf(rgb_k) primary_k`` with the primaries in absolute units (the display's white has
    its ``max_luminance_cd_m2``), converted to photons. The field of view follows from the display's pixel
    pitch (0.0254 / dpi m) and the viewing distance, which is the scene distance. The scene's
    ``illuminant_photons`` is the display white, so ``scene.reflectance()`` is linear RGB mixed spectrally.
    ISETCam: ``sceneFromFile(rgb, 'rgb', meanLuminance, display)``, except the field of view: a flat screen's,
    2 atan(w p / 2 d) (:meth:`Display.hfov_deg`), where ISETCam takes w atan(p / d) (58.2 against 53.9 degrees for
    1920 pixels at 96 dpi and 0.5 m); and ISETCam's default grid is the display's own, its primaries point-sampled.

    Args:
        rgb: encoded RGB [B, 3, H, W] (or [3, H, W]) in [0, 1].
        display: ``"lcd"`` (sRGB chromaticities and EOTF), ``"crt"``, ``"apple"`` (see :meth:`Display.create`)
            or a :class:`Display`.
        wavelengths: scene grid [L] (nm), default 400:10:700; the primaries are band-averaged onto it
            (:meth:`Display.primaries_on`), so the white's luminance moves by < 0.1 % on 400:10:700 and the
            primaries' chromaticities by up to 0.0013 in u'v' for ``"lcd"`` (narrow bands sampled every 10 nm;
            exact on its 1 nm grid), 0.0018 for ``"crt"``, 0.0027 for ``"apple"``.
        dpi, viewing_distance_m: override the display's.
        mean_luminance_cd_m2: None (default) keeps the display's absolute radiance (ISETCam's behaviour when no
            mean luminance is given); a value rescales the scene.

    Example:
        >>> lcd = Display.create("lcd")
        >>> s = from_rgb(torch.ones(1, 3, 2, 2), lcd, lcd.wavelengths_nm)  # on the display's own grid
        >>> round(s.mean_luminance().item(), 3)
        100.0
    """
    if not isinstance(rgb, torch.Tensor):
        raise TypeError(f"rgb: expected a torch.Tensor [B, 3, H, W], got {type(rgb).__name__}")
    if rgb.dim() == 3:
        rgb = rgb.unsqueeze(0)
    if rgb.dim() != 4 or rgb.shape[1] != 3:
        raise ValueError(f"rgb: expected shape [B, 3, H, W] (or [3, H, W]), got {tuple(rgb.shape)}")
    if not rgb.is_floating_point():
        raise TypeError(f"rgb: expected a floating tensor of encoded values in [0, 1], got {rgb.dtype} "
                        "(convert 8-bit images with rgb.float() / 255)")
    if dtype is None and rgb.dtype not in (torch.float32, torch.float64):  # (named the scene's dtype)
        raise TypeError(f"rgb: expected a float32 or float64 tensor with values in [0, 1], got {rgb.dtype} (or give "
                        f"the scene's dtype)")
    if isinstance(display, str):
        display = Display.create(display)
    elif not isinstance(display, Display):
        raise TypeError(f"display: expected a display name or a Display, got {type(display).__name__}")
    w = resolve_grid(wavelengths, dtype or rgb.dtype, device or rgb.device)
    rgb = rgb.to(dtype=w.dtype, device=w.device)
    pitch_dpi = display.dpi if dpi is None else check_float(dpi, "dpi", low=0.0, low_open=True)
    dist = display.viewing_distance_m if viewing_distance_m is None else check_float(
        viewing_distance_m, "viewing_distance_m", low=0.0, low_open=True)
    # rank 3 (Display.rgb_to_radiance factored): linear RGB maps x the primaries' photon spectra
    _check_rgb(rgb, "rgb", encoded=True)
    linear = display._eotf(rgb)  # (checked just above)
    primaries = spectral.energy_to_photons(display.primaries_on(w, dtype=w.dtype, device=w.device), w, dim=-1)
    if not bool((primaries.sum(dim=-1) > 0).any()):  # no primary's light on it (read "illuminant_photons: ... all
        # zeros"); a grid holding some primaries' light (620-700 nm: red only) renders, as before
        dw = display.wavelengths_nm
        raise ValueError(f"wavelengths: {float(w[0]):g}..{float(w[-1]):g} nm holds no light of display "
                         f"{display.name!r}'s primaries ({float(dw[0]):g}..{float(dw[-1]):g} nm)")
    photons = (linear, primaries.expand(linear.shape[0], -1, -1))
    white = display.linear_rgb_to_radiance(torch.ones(1, 3, 1, 1, dtype=w.dtype, device=w.device), w)[0, :, 0, 0]
    hfov = flat_screen_hfov_deg(rgb.shape[-1], pitch_dpi, dist)
    return finish(photons, w, hfov_deg=hfov, distance_m=dist, mean_luminance_cd_m2=mean_luminance_cd_m2,
                  illuminant_photons=white, name=f"rgb on {display.name}",
                  metadata={"display": display.name, "dpi": pitch_dpi, "viewing_distance_m": dist})
