"""Colour stages of the image processor: illuminant correction, sensor -> XYZ, XYZ -> display, encoding.

Conventions
-----------
* Images are ``[B, C, H, W]``; colour matrices are **left-multiplying** ``[K, C]`` (``out = M @ pixel``),
  optionally batched ``[B, K, C]``. ISETCam stores the transposed, right-multiplying matrix
  (``imageLinearTransform(img, T)``, ``T = M.T``).
* Spectral data follow :mod:`isettorch.spectral`: illuminants are energy SPDs ``[L]`` (W/...), sensor QE
  is per photon ``[C, L]``, so sensor responses are ``sum QE * photons * R * dl`` and XYZ is
  ``683 sum cmf * energy * R * dl`` (CIE 015:2018). A sensor whose QE is a linear combination of the
  *photon* colour matching functions ``cmf(l) * h c / l`` (ISETCam's ``XYZQuanta``) is colorimetric.
* Every matrix a stage uses is kept as a buffer or attribute so it can be inspected and replaced.

References: ISETCam ``imageSensorTransform``, ``ieColorTransform``, ``imageIlluminantCorrection``,
``ieInternal2Display``, ``displayRender``; IEC 61966-2-1:1999 (sRGB).
"""

from __future__ import annotations

import functools
import math
import numbers

import torch
from torch import nn

from .. import spectral
from .._checks import (
    as_tensor,
    check_bool,
    check_finite,
    check_rank,
    check_wavelengths,
    is_real,
    warn_caller,
)
from ..image import XYZ_TO_LINEAR_SRGB, bradford_matrix, srgb_decode, srgb_encode  # re-exported here

__all__ = [
    "apply_matrix",
    "apply_gains",
    "fit_colour_matrix",
    "reflectance_set",
    "sensor_responses",
    "xyz_responses",
    "sensor_to_xyz_matrix",
    "white_xyz",
    "check_illuminant_name",
    "gray_world_gains",
    "white_world_gains",
    "illuminant_gains",
    "ILLUMINANT_CORRECTION_METHODS",
    "display_rgb_to_xyz_matrix",
    "bradford_matrix",
    "xyz_to_display_matrix",
    "srgb_encode",
    "srgb_decode",
    "IlluminantCorrection",
    "SensorToXYZ",
    "XYZToDisplay",
    "DisplayEncode",
]


# ---------------------------------------------------------------------------------------------
# Linear algebra on images


def _check_image(img: torch.Tensor, name: str = "img") -> None:
    if not isinstance(img, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor (B, C, H, W), got {type(img).__name__}")
    check_rank(img, 4, name, "(B, C, H, W)")
    if not img.is_floating_point():  # (an integer image cast a 0.5 gain or matrix entry to 0)
        raise TypeError(f"{name}: expected a floating-point image (linear values), got {img.dtype}")


def apply_matrix(img: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor:
    """Apply a colour matrix to every pixel: ``out[b, k] = sum_c M[k, c] img[b, c]``.

    Args:
        img: (B, C, H, W).
        matrix: (K, C) or (B, K, C), left-multiplying (ISETCam's ``T`` is ``matrix.T``).

    Returns:
        (B, K, H, W).

    Example:
        >>> apply_matrix(torch.ones(1, 3, 2, 2), torch.eye(3)).shape
        torch.Size([1, 3, 2, 2])
    """
    _check_image(img)
    m = as_tensor(matrix, "matrix")
    check_finite(m.detach(), "matrix")
    return _apply_matrix(img, m)


def _apply_matrix(img: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor:
    """:func:`apply_matrix` for the pipeline's stages, whose matrices were checked when set (no host read)."""
    # the image's device: a processor left on the CPU still runs
    m = matrix.to(device=img.device, dtype=img.dtype)
    if m.dim() not in (2, 3) or m.shape[-1] != img.shape[1]:
        raise ValueError(f"matrix: expected shape (K, {img.shape[1]}) or (B, K, {img.shape[1]}) for an image with "
                         f"{img.shape[1]} channels, got {tuple(m.shape)}")
    if m.dim() == 2:
        return torch.einsum("kc,bchw->bkhw", m, img)
    if m.shape[0] not in (1, img.shape[0]):
        raise ValueError(f"matrix: expected a batch of 1 or {img.shape[0]} matrices, got {m.shape[0]}")
    return torch.einsum("bkc,bchw->bkhw", m.expand(img.shape[0], -1, -1), img)


def apply_gains(img: torch.Tensor, gains: torch.Tensor) -> torch.Tensor:
    """Per-channel gains (a diagonal matrix): (B, C, H, W) * gains (C,) or (B, C)."""
    _check_image(img)
    return _apply_gains(img, _check_gains(gains, like=img))


def _apply_gains(img: torch.Tensor, gains: torch.Tensor) -> torch.Tensor:
    """:func:`apply_gains` for the white-balance stage, whose gains are checked where they are made."""
    g = gains.to(device=img.device, dtype=img.dtype)
    if g.dim() == 1:
        g = g.unsqueeze(0)
    if g.dim() != 2 or g.shape[-1] != img.shape[1] or g.shape[0] not in (1, img.shape[0]):
        raise ValueError(f"gains: expected shape ({img.shape[1]},) or ({img.shape[0]}, {img.shape[1]}), "
                         f"got {tuple(gains.shape)}")
    return img * g[:, :, None, None]


#: the condition number above which :func:`fit_colour_matrix` warns (a Bayer RGB sensor's fit on the Macbeth chart
#: has about 7, an RGBW one about 400: W is nearly R + G + B)
ILL_CONDITIONED = 1e6


def fit_colour_matrix(source: torch.Tensor, target: torch.Tensor, white=None) -> torch.Tensor:
    """Least-squares colour matrix ``M`` (K, C) minimising ``||source @ M.T - target||_F``.

    Args:
        source: (N, C) responses of N samples (e.g. sensor RGB of the Macbeth patches).
        target: (N, K) the desired values (e.g. their XYZ).
        white: None, or ``(source_white (C,), target_white (K,))``: the least-squares matrix under the constraint
            ``M source_white = target_white`` exactly (white-point preserving regression, Finlayson & Drew, J.
            Electronic Imaging 6(4), 1997: for each output, ``x = x_ls + G^-1 w_s (t - w_s . x_ls) / (w_s^T G^-1
            w_s)`` with ``G = source^T source``), so a neutral renders neutral.

    Returns:
        (K, C), solved in float64 (``torch.linalg.lstsq``), returned in ``source``'s dtype.
        Differentiable for full-rank ``source``.

    Reference: ISETCam ``imageSensorTransform`` (``T = sensorResponse \\ targetResponse``).

    Example:
        >>> s = torch.rand(24, 3, dtype=torch.float64); m = torch.rand(3, 3, dtype=torch.float64)
        >>> torch.allclose(fit_colour_matrix(s, s @ m.T), m)
        True
    """
    check_rank(source, 2, "source", "(N, C)")
    check_rank(target, 2, "target", "(N, K)")
    if source.shape[0] != target.shape[0]:
        raise ValueError(f"target: expected {source.shape[0]} rows to match source, got {target.shape[0]}")
    if source.shape[0] < source.shape[1]:
        raise ValueError(f"source: expected at least as many samples as channels, got shape {tuple(source.shape)}")
    check_finite(source.detach(), "source")
    check_finite(target.detach(), "target")
    dtype = source.dtype if source.is_floating_point() else torch.get_default_dtype()
    a = source.to(torch.float64)
    b = target.to(device=a.device, dtype=torch.float64)
    # Scale columns so the fit is well conditioned whatever the units (photons vs cd/m^2).
    col = a.abs().amax(dim=0).clamp_min(torch.finfo(torch.float64).tiny)
    rank = int(torch.linalg.matrix_rank(a / col))
    if rank < a.shape[1]:  # lstsq would silently return the minimum-norm one of infinitely many matrices
        raise ValueError(f"source: its {a.shape[1]} channels are linearly dependent over the samples (rank {rank}): "
                         "the colour matrix is not determined (two identical channels, a dark channel, or too few "
                         "distinct colours)")
    sv = torch.linalg.svdvals(a.detach() / col)
    cond = float(sv[0] / sv[-1])
    if cond > ILL_CONDITIONED:  # determined, but barely: the matrix's large, opposed coefficients amplify noise
        warn_caller(f"source: the colour fit is ill-conditioned (condition number {cond:.3g} of the source's "
                    f"{a.shape[1]} channels over {a.shape[0]} samples, each channel scaled to max 1; an RGB sensor "
                    f"on the Macbeth chart has about 7, RGBW about 400): the fitted matrix amplifies errors in the "
                    f"sensor values up to that factor. Channels nearly proportional to each other or to a sum of "
                    f"others, or too few distinct colours, do this")
    sol = torch.linalg.lstsq(a / col, b, driver="gelsd" if a.device.type == "cpu" else None).solution
    if white is not None:
        try:
            ws, wt = white
        except (TypeError, ValueError):
            raise ValueError(f"white: expected (source_white (C,), target_white (K,)), got {white!r}") from None
        ws = as_tensor(ws, "white", dtype=torch.float64).to(a.device).reshape(-1)
        wt = as_tensor(wt, "white", dtype=torch.float64).to(a.device).reshape(-1)
        if ws.numel() != a.shape[1] or wt.numel() != b.shape[1]:
            raise ValueError(f"white: expected a source white of {a.shape[1]} and a target white of {b.shape[1]} "
                             f"values, got {ws.numel()} and {wt.numel()}")
        ws = ws / col  # in the scaled columns
        check_finite(ws.detach(), "white")
        check_finite(wt.detach(), "white")
        if not bool((ws != 0).any()):
            raise ValueError("white: the source white is zero; there is no white to preserve")
        gw = torch.linalg.solve((a / col).T @ (a / col), ws)  # G^-1 w_s (G full rank: checked above)
        sol = sol + gw[:, None] * ((wt - ws @ sol) / (ws @ gw))[None, :]
    return (sol / col[:, None]).T.to(dtype)


# ---------------------------------------------------------------------------------------------
# Spectral responses of reflectance sets


@functools.cache
def _rawtoaces_native() -> tuple:
    import numpy as np
    from colour.characterisation import read_training_data_rawtoaces_v1

    msds = read_training_data_rawtoaces_v1()
    return np.asarray(msds.wavelengths, float), np.asarray(msds.values, float).T.copy()


def _macbeth_reflectances(w: torch.Tensor) -> torch.Tensor:
    """The Macbeth chart's reflectances [24, L]: the one loader, :func:`isettorch.scene.macbeth_reflectances`
    (BabelColor average, end values held outside 380-730 nm), so the fit, the chart and the scene agree."""
    from ..scene import macbeth_reflectances  # imported on use: isp loads without the scene package

    return macbeth_reflectances(w.to(torch.float64).cpu(), dtype=torch.float64)


REFLECTANCE_SETS = ("macbeth", "rawtoaces190", "macbeth+rawtoaces190")


def reflectance_set(name: str, wavelengths_nm, *, dtype=None, device=None) -> torch.Tensor:
    """Surface reflectances (N, L) on a grid: ``"macbeth"`` (24 ColorChecker patches,
    :func:`isettorch.scene.macbeth_reflectances`), ``"rawtoaces190"`` (the 190 training reflectances of
    the Academy's rawtoaces IDT, via colour-science) or ``"macbeth+rawtoaces190"``; both sets hold their end values
    beyond their data (380-730 and 380-780 nm: :func:`~isettorch.spectral.resample_held`).

    Reference: ISETCam ``imageSensorTransform`` surfaces ``'mcc'`` / ``'multisurface'``.
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    dtype = spectral.table_dtype(w, dtype)
    key = str(name).lower()
    if key in ("macbeth", "mcc"):
        r = _macbeth_reflectances(w)
    elif key in ("rawtoaces190", "multisurface"):
        src, vals = _rawtoaces_native()
        # end values held beyond the data's 380-780 nm, as the Macbeth set's (they dropped to 0: a sensor with
        # near-infrared response fitted on 380-830 nm got responses up to 82 % off)
        r = spectral.resample_held(torch.from_numpy(vals), torch.from_numpy(src), w.to(torch.float64).cpu())
    elif key == "macbeth+rawtoaces190":
        r = torch.cat([reflectance_set("macbeth", w, dtype=torch.float64).cpu(),
                       reflectance_set("rawtoaces190", w, dtype=torch.float64).cpu()])
    else:
        raise ValueError(f"name: unknown reflectance set {name!r}; expected one of {list(REFLECTANCE_SETS)}")
    return r.to(dtype=dtype, device=device or w.device)


def _illuminant_energy(illuminant, w: torch.Tensor) -> torch.Tensor:
    if isinstance(illuminant, str):
        return spectral.illuminant(illuminant, w, dtype=torch.float64)
    t = as_tensor(illuminant, "illuminant", dtype=torch.float64).reshape(-1)
    if t.numel() != w.numel():
        raise ValueError(f"illuminant: expected an energy SPD with {w.numel()} samples (one per wavelength), "
                         f"got {t.numel()}")
    check_finite(t, "illuminant")
    return t.to(w.device)


def sensor_responses(qe: torch.Tensor, wavelengths_nm, illuminant="D65", reflectances=None) -> torch.Tensor:
    """Sensor responses (N, C) of surfaces under an illuminant: ``sum_l R(l) P(l) QE_c(l) dl``.

    ``P`` is the illuminant in photons (from its energy SPD); units are relative (ISETCam
    ``imageSensorTransform``: ``sensorQE' * diag(illQuanta) * surRef``). ``reflectances`` is (N, L)
    or a set name (default ``"macbeth"``).
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm)).to(torch.float64)
    check_rank(qe, 2, "qe", "(C, L)")
    if qe.shape[-1] != w.numel():
        raise ValueError(f"qe: expected {w.numel()} wavelengths (last dim), got shape {tuple(qe.shape)}")
    refl = _reflectances(reflectances, w)
    e = _illuminant_energy(illuminant, w.to(qe.device))
    p = spectral.energy_to_photons(e, w.to(qe.device), dim=0)
    dl = spectral.wavelength_weights(w).to(qe.device)
    return (refl.to(qe.device, torch.float64) * (p * dl)) @ qe.to(torch.float64).T


def _reflectances(reflectances, w: torch.Tensor) -> torch.Tensor:
    """Surfaces ``(N, L)`` on the wavelengths ``w``: a named set (default the Macbeth chart) or a tensor, whose
    wavelength count and values are checked (a wrong length raised a bare broadcasting error, NaN gave a NaN
    matrix reported later as ``source``)."""
    if reflectances is None or isinstance(reflectances, str):
        return reflectance_set(reflectances or "macbeth", w)
    refl = as_tensor(reflectances, "reflectances")
    if refl.dim() != 2 or refl.shape[-1] != w.numel():
        raise ValueError(f"reflectances: expected (N, {w.numel()}) surfaces on the {w.numel()} wavelengths, got shape "
                         f"{tuple(refl.shape)}")
    check_finite(refl.detach(), "reflectances")
    return refl


def xyz_responses(wavelengths_nm, illuminant="D65", reflectances=None, observer: str = "1931") -> torch.Tensor:
    """CIE XYZ (N, 3) of surfaces under an illuminant, ``683 sum R E cmf dl`` (CIE 015:2018)."""
    w = check_wavelengths(torch.as_tensor(wavelengths_nm)).to(torch.float64)
    refl = _reflectances(reflectances, w)
    e = _illuminant_energy(illuminant, w)
    return spectral.xyz_of_energy(refl.to(torch.float64).cpu() * e.cpu(), w, dim=-1, observer=observer)


def sensor_to_xyz_matrix(qe: torch.Tensor, wavelengths_nm, illuminant="D65", surfaces="macbeth",
                         observer: str = "1931", white_preserving: bool = False) -> torch.Tensor:
    """Sensor -> XYZ matrix (3, C) fitted by least squares on surfaces under an illuminant.

    With ``surfaces="macbeth"`` and ``illuminant="D65"`` this is ISETCam's ``'MCC optimized'``
    conversion (``ieColorTransform(sensor, 'XYZ', 'D65', 'mcc')``) on the BabelColor chart data: ISETCam's own
    ``macbethChart.mat`` differs, and its matrix for the ``isetcam_default`` sensor differs from this one by up to
    0.6 % of the largest entry; on ISETCam's own patches this fit reproduces ISETCam's to 2e-7. The matrix maps the
    sensor's response (in QE x photon units, any common scale) to XYZ in the same scale.

    Args:
        qe: (C, L) spectral quantum efficiency on ``wavelengths_nm``.
        illuminant: a name for :func:`isettorch.spectral.illuminant` or an energy SPD (L,).
        surfaces: a :func:`reflectance_set` name or reflectances (N, L).
        white_preserving: fit under the constraint that a perfect white under ``illuminant`` maps to its XYZ
            exactly (:func:`fit_colour_matrix` with ``white``; not ISETCam's fit, which leaves the white's colour
            free: with the ``isetcam_default`` sensor a D65 white renders at a* = -3.5).

    Example:
        >>> w = torch.arange(400., 701., 10.)
        >>> q = spectral.cmfs(w) * 1e-3 / w  # photon CMFs: a colorimetric sensor
        >>> m = sensor_to_xyz_matrix(q, w); m.shape
        torch.Size([3, 3])
    """
    src = sensor_responses(qe, wavelengths_nm, illuminant, surfaces)
    tgt = xyz_responses(wavelengths_nm, illuminant, surfaces, observer).to(src.device)
    white = None
    if white_preserving:
        ones = torch.ones(1, torch.as_tensor(wavelengths_nm).numel(), dtype=torch.float64)
        white = (sensor_responses(qe, wavelengths_nm, illuminant, ones)[0],
                 xyz_responses(wavelengths_nm, illuminant, ones, observer)[0].to(src.device))
    return fit_colour_matrix(src, tgt, white).to(qe.dtype if qe.is_floating_point() else torch.get_default_dtype())


def white_xyz(illuminant="D65", wavelengths_nm=None, observer: str = "1931") -> torch.Tensor:
    """XYZ (3,) of a perfect white under an illuminant, normalised to Y = 1."""
    w = spectral.default_wavelengths(380.0, 780.0, 5.0, dtype=torch.float64) if wavelengths_nm is None \
        else check_wavelengths(torch.as_tensor(wavelengths_nm)).to(torch.float64)
    xyz = xyz_responses(w, illuminant, torch.ones(1, w.numel(), dtype=torch.float64), observer)[0]
    if not float(xyz[1]) > 0:
        raise ValueError(f"illuminant: expected a spectrum with luminance on {float(w[0]):g}-{float(w[-1]):g} nm, got "
                         f"Y = {float(xyz[1]):.6g} (a zero or negative spectrum has no white)")
    return xyz / xyz[1]


def check_illuminant_name(name, key: str = "illuminant") -> None:
    """A named illuminant (:func:`isettorch.spectral.illuminant`) is one the library has, checked when a stage is
    built: ValueError naming ``key``, the name and the accepted forms (``'D66'`` reads as daylight at 66 K, which
    is no daylight). Non-strings (an SPD) are left to the stage."""
    if not isinstance(name, str):
        return
    try:
        spectral.illuminant(name, torch.tensor([550.0], dtype=torch.float64))
    except ValueError as err:
        raise ValueError(f"{key}: {name!r} is not a valid illuminant name; expected one of "
                         f"{spectral.illuminant_names()}, 'D<cct>' (CIE daylight at a CCT of 4000-25000 K, e.g. "
                         f"'D5000') or 'blackbody<T>' / 'BB<T>' (T in kelvin, e.g. 'blackbody3000') ({err})") from err


# ---------------------------------------------------------------------------------------------
# Illuminant correction (white balance)


NO_SIGNAL = ("raise", "white")  # what gray / white world do with an item that has a channel mean <= 0
#: a channel mean at or below this fraction of the item's largest one is no signal for gray / white world (a gain
#: beyond 1e4, or all others' below 1e-4: a menon2007 demosaic's leak of 1.8e-5 into a black red channel took the
#: imx363 camera's gains to [1, 1.8e-5, 1.8e-5], the image crushed to black, where an exact 0 was refused)
NO_SIGNAL_FRACTION = 1e-4


def _check_no_signal(no_signal) -> str:
    if no_signal not in NO_SIGNAL:
        raise ValueError(f"no_signal: expected one of {NO_SIGNAL}, got {no_signal!r}")
    return no_signal


def _gains_from_means(means: torch.Tensor, white: torch.Tensor, reference_channel: int, name: str,
                      no_signal: str = "raise") -> torch.Tensor:
    # ISETCam grayWorld/whiteWorld: D_c = (white_c / white_ref) * (avg_ref / avg_c). An image that is black in
    # every channel has nothing to balance: it gets the white's own gains (its output stays black; a black frame
    # of a dim scene, or one black item, failed the whole batch). An item with a channel mean <= 0 but not all
    # black (a single-hue image; a dim noisy frame, whose means above black are noise of either sign) has no
    # gray-world gain: an error, or with no_signal='white' the white's own gains too, with a warning
    _check_no_signal(no_signal)  # (checked on every call, not only when an item needs it)
    m = means.detach()
    if not bool(torch.isfinite(m).all()):  # (a NaN or Inf pixel gave NaN gains)
        raise ValueError(f"{name}: every channel needs a finite, positive mean to be balanced, got channel means "
                         f"{means.detach().tolist()}")
    black = (m == 0).all(dim=-1, keepdim=True)
    floor = (NO_SIGNAL_FRACTION * m.amax(dim=-1, keepdim=True)).clamp_min(0)
    unbalanced = (m <= floor).any(dim=-1, keepdim=True) & ~black
    if bool(unbalanced.any()):
        items = unbalanced[:, 0].nonzero()[:, 0].tolist()
        if no_signal == "raise":
            raise ValueError(f"{name}: every channel needs a finite, positive mean to be balanced (above "
                             f"{NO_SIGNAL_FRACTION:g} of the largest channel's; or the whole image black), got channel "
                             f"means {means.detach().tolist()}")
        warn_caller(f"white balance: item(s) {items} have a channel whose mean is <= 0 or at most "
                    f"{NO_SIGNAL_FRACTION:g} of the largest channel's (no signal above black there: a dark noisy "
                    f"frame or a single-hue image), so no gray-world gains exist; they get the white's own gains (not "
                    f"balanced)")
    means = torch.where(black | unbalanced, torch.ones_like(means), means)
    wt = white.to(device=means.device, dtype=means.dtype)
    if wt.dim() == 1:
        wt = wt.unsqueeze(0)
    if wt.shape[-1] != means.shape[-1]:
        raise ValueError(f"white: expected {means.shape[-1]} channel values, got shape {tuple(white.shape)}")
    if not bool(torch.isfinite(wt.detach()).all()) or (wt.detach() <= 0).any():
        raise ValueError(f"white: expected positive, finite channel values of the target white, got {wt.tolist()}")
    r = _check_reference_channel(reference_channel, means.shape[-1])
    gains = (wt / wt[:, r:r + 1]) * (means[:, r:r + 1] / means)
    over = ~torch.isfinite(gains.detach()).all(dim=-1, keepdim=True)  # (a channel mean of 1e-39 in float32: inf)
    if bool(over.any()):
        if no_signal == "raise":
            raise ValueError(f"{name}: the channel means {means.detach().tolist()} give gains beyond "
                             f"{means.dtype}'s range ({gains.detach().tolist()}); a channel has next to no signal")
        warn_caller(f"white balance: item(s) {over[:, 0].nonzero()[:, 0].tolist()} have a channel mean so small "
                    f"that its gain is beyond {means.dtype}'s range; they get the white's own gains (not balanced)")
        gains = torch.where(over, (wt / wt[:, r:r + 1]).expand_as(gains), gains)
    return gains


def _check_reference_channel(reference_channel, channels: int | None = None) -> int:
    """``reference_channel`` as a channel index (of ``channels`` when known), else a ValueError naming it."""
    if isinstance(reference_channel, bool) or not isinstance(reference_channel, numbers.Integral) \
            or not 0 <= reference_channel < (channels if channels is not None else math.inf):
        expected = "a channel index >= 0" if channels is None else f"a channel index in 0..{channels - 1}"
        raise ValueError(f"reference_channel: expected {expected}, got {reference_channel!r}")
    return int(reference_channel)


def _check_criterion(criterion) -> float:
    """White world's bright-pixel ``criterion``, a fraction in (0, 1], else a ValueError naming it."""
    if not (is_real(criterion) and 0 < criterion <= 1):
        raise ValueError(f"criterion: expected a fraction in (0, 1], got {criterion!r}")
    return float(criterion)


def _check_gains(gains, *, like: torch.Tensor | None = None) -> torch.Tensor:
    """Manual white-balance ``gains`` (C,) or (B, C): finite and positive, else a ValueError naming them."""
    g = as_tensor(gains, "gains") if like is None else as_tensor(gains, "gains", dtype=like.dtype, device=like.device)
    check_finite(g.detach(), "gains")
    if bool((g <= 0).any()):
        raise ValueError(f"gains: expected positive per-channel gains, got {g.tolist()}")
    return g


def _default_white(img: torch.Tensor, white) -> torch.Tensor:
    if white is None:
        return torch.ones(img.shape[1], dtype=img.dtype, device=img.device)
    w = as_tensor(white, "white", dtype=img.dtype, device=img.device)
    # (C,) or (B, C) for the image's (B, C, ...): a (2, 1, 3) white had given (2, 2, 3) gains, a (3, 3) one for a
    # batch of 2 a bare broadcasting error
    b, c = img.shape[0], img.shape[1]
    if not (w.shape == (c,) or w.shape == (b, c)):
        raise ValueError(f"white: expected shape ({c},) or ({b}, {c}) for an image of {b} item(s) and {c} channels, "
                         f"got {tuple(w.shape)}")
    return w


def gray_world_gains(img: torch.Tensor, white=None, reference_channel: int = 0, *, no_signal: str = "raise",
                     ) -> torch.Tensor:
    """Gray-world gains (B, C): after them every channel mean is proportional to ``white``.

    Args:
        img: (B, C, H, W), linear.
        white: (C,) or (B, C) channel values of the target white in the image's space (default all ones,
            ISETCam's assumption in sensor space; in XYZ use :func:`white_xyz`).
        reference_channel: the channel whose gain is 1 (ISETCam keeps the first).
        no_signal: an item with a channel mean <= 0 (or at most :data:`NO_SIGNAL_FRACTION` of its largest channel
            mean) and not black in every channel (a single-hue image; a dim noisy frame, whose means above black
            are noise of either sign) has no gray-world gains: ``"raise"``
            (default) a ValueError, ``"white"`` the white's own gains for that item, with a warning (the ISP's
            :class:`IlluminantCorrection`, so that one dark item does not fail a batch). A black item always gets
            the white's own gains.

    Every pixel counts, saturated ones too (as in ISETCam): clip or mask a raw's saturated pixels first if they
    should not pull the means.

    Reference: Buchsbaum, J. Franklin Inst. 310 (1980); ISETCam ``imageIlluminantCorrection`` (grayWorld).
    """
    _check_image(img)
    return _gains_from_means(img.mean(dim=(-2, -1)), _default_white(img, white), reference_channel, "img", no_signal)


def white_world_gains(img: torch.Tensor, white=None, reference_channel: int = 0,
                      criterion: float = 0.7, *, no_signal: str = "raise") -> torch.Tensor:
    """White-world gains (B, C): the mean of the bright pixels (those where the channel with the
    highest maximum is >= ``criterion`` x its maximum) is mapped to ``white``. ``no_signal``: as in
    :func:`gray_world_gains`.

    Saturated pixels are among the bright ones and count with their values (as in ISETCam): clip them to the white
    level first, or a clipped highlight's channels pull the gains (one pixel at (1.6, 0.9, 0.8) moves them from
    (1, 1.11, 1.25) to (1, 1.78, 2)).

    The bright pixels are chosen on one plane (ISETCam's rule), so under a coloured light they include bright
    saturated surfaces of that light's hue, not whites only: the Macbeth chart under illuminant A in XYZ (one pixel a
    patch, target the D65 white) selects the yellow patch beside the white one, and the white renders at b* -30
    (gains (0.84, 1, 4.84) against the white patch's own (0.87, 1, 3.17)). Gray world, or a white known to be in
    the scene, is the safer choice under a strongly coloured light.

    Reference: ISETCam ``imageIlluminantCorrection`` (whiteWorld, criterion 0.7).
    """
    _check_image(img)
    _check_criterion(criterion)
    flat = img.flatten(2)  # B, C, N
    peak = flat.detach().amax(dim=2)  # B, C
    plane = peak.argmax(dim=1)  # B
    bright_plane = flat.detach()[torch.arange(img.shape[0], device=img.device), plane]  # B, N
    mask = (bright_plane >= criterion * peak.amax(dim=1, keepdim=True)).to(img.dtype)  # B, N
    means = (flat * mask[:, None]).sum(2) / mask.sum(1, keepdim=True).clamp_min(1)
    return _gains_from_means(means, _default_white(img, white), reference_channel, "img", no_signal)


ILLUMINANT_CORRECTION_METHODS = ("none", "gray_world", "white_world", "manual")


def illuminant_gains(img: torch.Tensor, method: str = "gray_world", white=None, gains=None,
                     reference_channel: int = 0, criterion: float = 0.7, *, no_signal: str = "raise") -> torch.Tensor:
    """Gains (B, C) for an illuminant-correction ``method`` in ``ILLUMINANT_CORRECTION_METHODS`` (``no_signal``: as
    in :func:`gray_world_gains`)."""
    _check_image(img)
    _check_no_signal(no_signal)
    key = str(method).lower().replace(" ", "_").replace("-", "_")
    if gains is not None and key != "manual":  # (ignored; the IlluminantCorrection constructor refuses it)
        raise ValueError(f"gains: only illuminant correction 'manual' uses gains; method {method!r} computes its own")
    if key == "none":
        return torch.ones(img.shape[0], img.shape[1], dtype=img.dtype, device=img.device)
    if key in ("gray_world", "grey_world"):
        return gray_world_gains(img, white, reference_channel, no_signal=no_signal)
    if key == "white_world":
        return white_world_gains(img, white, reference_channel, criterion, no_signal=no_signal)
    if key == "manual":
        if gains is None:
            raise ValueError("gains: method 'manual' needs gains (C,) or (B, C), got None")
        g = _check_gains(gains, like=img)
        g = g.unsqueeze(0) if g.dim() == 1 else g
        if g.dim() != 2 or g.shape[-1] != img.shape[1] or g.shape[0] not in (1, img.shape[0]):
            raise ValueError(f"gains: expected ({img.shape[1]},) or ({img.shape[0]}, {img.shape[1]}) for the image's "
                             f"{img.shape[0]} items, got {tuple(g.shape)}")
        return g.expand(img.shape[0], -1)
    raise ValueError(f"method: unknown illuminant correction {method!r}; expected one of "
                     f"{list(ILLUMINANT_CORRECTION_METHODS)}")


# ---------------------------------------------------------------------------------------------
# Display


def display_rgb_to_xyz_matrix(primaries_energy: torch.Tensor, wavelengths_nm, observer: str = "1931") -> torch.Tensor:
    """XYZ of a display's primaries at full drive, as the columns of a (3, 3) matrix.

    ``primaries_energy`` is (3, L) (or (L, 3)) spectral radiance in W/sr/m^2/nm, so the matrix is in
    cd/m^2 and its row sums are the white point; ``683 sum spd cmf dl`` (CIE 015:2018; ISETCam
    ``displayGet(d, 'rgb2xyz')`` transposed).
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    spd = as_tensor(primaries_energy, "primaries_energy")
    check_rank(spd, 2, "primaries_energy", "(3, L)")
    if spd.shape[0] != 3 and spd.shape[1] == 3:
        spd = spd.T
    if spd.shape != (3, w.numel()):
        raise ValueError(f"primaries_energy: expected shape (3, {w.numel()}), got {tuple(spd.shape)}")
    check_finite(spd, "primaries_energy")
    return spectral.xyz_of_energy(spd.to(torch.float64), w, dim=-1, observer=observer).T


def xyz_to_display_matrix(rgb_to_xyz: torch.Tensor, relative: bool = True) -> torch.Tensor:
    """Inverse of a display's RGB -> XYZ matrix (3, 3). With ``relative`` the display white has Y = 1,
    so XYZ scaled to a white of Y = 1 maps that white to RGB (1, 1, 1) (ISETCam ``ieInternal2Display``)."""
    m = as_tensor(rgb_to_xyz, "rgb_to_xyz").to(torch.float64)
    if m.shape != (3, 3):
        raise ValueError(f"rgb_to_xyz: expected a (3, 3) matrix, got {tuple(m.shape)}")
    if relative:
        m = m / m[1].sum()
    return torch.linalg.inv(m)


# ---------------------------------------------------------------------------------------------
# Thin modules


class IlluminantCorrection(nn.Module):
    """Illuminant correction (white balance) by per-channel gains, in sensor space or in XYZ.

    Args:
        method: ``"none"``, ``"gray_world"``, ``"white_world"`` or ``"manual"``.
        space: ``"xyz"`` (after the sensor -> XYZ matrix, ISETCam's default place) or ``"sensor"``.
        gains: manual gains (C,) when ``method="manual"``.
        reference_channel: channel whose gain is 1 (ISETCam: the first).
        criterion: bright-pixel threshold of white world (ISETCam: 0.7).

    ``forward(img, white)`` returns the corrected (B, C, H, W) image; the gains it used are kept in
    ``last_gains`` (B, C). An item that gray or white world cannot balance (a channel mean <= 0, or at most
    :data:`NO_SIGNAL_FRACTION` of the largest: a dark noisy frame, a single-hue image) keeps the white's own gains,
    with a warning (``no_signal='white'`` of
    :func:`gray_world_gains`): one such item does not fail a batch.

    Example:
        >>> ic = IlluminantCorrection("gray_world", space="sensor")
        >>> out = ic(torch.rand(1, 3, 4, 4) + 0.1, white=torch.ones(3))
        >>> torch.allclose(out.mean((-2, -1)), out.mean((-2, -1))[:, :1].expand(-1, 3))
        True
    """

    def __init__(self, method: str = "none", space: str = "xyz", gains=None, reference_channel: int = 0,
                 criterion: float = 0.7) -> None:
        super().__init__()
        key = str(method).lower().replace(" ", "_").replace("-", "_")
        key = "gray_world" if key == "grey_world" else key
        if key not in ILLUMINANT_CORRECTION_METHODS:
            raise ValueError(f"method: unknown illuminant correction {method!r}; expected one of "
                             f"{list(ILLUMINANT_CORRECTION_METHODS)}")
        if space not in ("xyz", "sensor"):
            raise ValueError(f"space: expected 'xyz' or 'sensor', got {space!r}")
        if key == "manual" and gains is None:
            raise ValueError("gains: method 'manual' needs gains (C,), got None")
        if key != "manual" and gains is not None:
            raise ValueError(f"gains: only illuminant correction 'manual' uses gains; method {method!r} computes its "
                             f"own (drop gains, or use method 'manual')")
        if gains is not None:
            gains = _check_gains(gains)  # (C,) or (B, C) per item (a (B, C) was flattened to (B C,))
            if gains.dim() > 2:
                raise ValueError(f"gains: expected (C,) or (B, C), got shape {tuple(gains.shape)}")
        self.method = key
        self.space = space
        # checked against the channel count with the gains
        self.reference_channel = _check_reference_channel(reference_channel)
        self.criterion = _check_criterion(criterion)  # (checked only at the first forward)
        self.register_buffer("gains", gains)
        self.register_buffer("last_gains", None, persistent=False)

    def forward(self, img: torch.Tensor, white=None) -> torch.Tensor:
        g = illuminant_gains(img, self.method, white, self.gains, self.reference_channel, self.criterion,
                             no_signal="white")
        self.last_gains = g.detach()
        return img if self.method == "none" else _apply_gains(img, g)

    def extra_repr(self) -> str:
        return f"method={self.method!r}, space={self.space!r}"


class SensorToXYZ(nn.Module):
    """Sensor -> XYZ colour matrix (3, C): given, or fitted on surfaces under an illuminant.

    Args:
        matrix: a fixed (3, C) matrix; if None it is fitted by :meth:`fit` from the sensor's QE.
        illuminant, surfaces, observer: the fit's settings (:func:`sensor_to_xyz_matrix`); the default is
            ISETCam's ``'MCC optimized'`` (Macbeth chart under D65).
        learnable: make the matrix an ``nn.Parameter``: the given matrix, or the first fit (the first
            :meth:`fit`, or the first camera forward, which fits it; build the optimiser after it). Later fits
            leave a learnable matrix alone (they update ``sensor_white`` only), so the optimiser keeps training the
            parameter the module uses, even when the filters learn too.
        normalize: scale the fitted matrix so that a perfect white under ``illuminant`` whose brightest
            channel is at the white level (sensor value 1) maps to Y = 1 (exposure-referred XYZ).
        white_preserving: fit under the constraint that that white maps to the illuminant's white chromaticity
            exactly (:func:`sensor_to_xyz_matrix`); default False, ISETCam's unconstrained fit.

    Buffers: ``matrix`` (3, C), ``sensor_white`` (C,), the sensor's response to that white (max 1), and ``fitted``:
    whether the matrix is the fit's (it follows the QE, also after a checkpoint is loaded) or given.

    Example:
        >>> w = torch.arange(400., 701., 10.)
        >>> s2x = SensorToXYZ().fit(spectral.cmfs(w) / w, w)
        >>> s2x(torch.rand(2, 3, 4, 4)).shape
        torch.Size([2, 3, 4, 4])
    """

    def __init__(self, matrix=None, illuminant="D65", surfaces="macbeth", observer: str = "1931",
                 learnable: bool = False, normalize: bool = True, white_preserving: bool = False) -> None:
        super().__init__()
        check_illuminant_name(illuminant)
        self.white_preserving = check_bool(white_preserving, "white_preserving")  # (bool('False') was True)
        self.illuminant = illuminant
        if isinstance(surfaces, str):  # (an unknown name had failed only at the fit, as 'name: ...')
            try:
                reflectance_set(surfaces, torch.tensor([550.0], dtype=torch.float64))
            except ValueError as err:
                raise ValueError(f"surfaces: {str(err).partition(': ')[2]}") from err
        self.surfaces = surfaces
        self.observer = observer
        self.learnable = check_bool(learnable, "learnable")
        self.normalize = check_bool(normalize, "normalize")
        self._fit_key = None
        self.register_buffer("matrix", None)
        self.register_buffer("sensor_white", None)
        # whether the matrix is the fit's (it follows the QE) or given (set_matrix): a checkpoint says which
        self.register_buffer("fitted", torch.tensor(False))
        if matrix is not None:
            self.set_matrix(as_tensor(matrix, "matrix"))

    def set_matrix(self, matrix: torch.Tensor) -> SensorToXYZ:
        """Use a given (3, C) matrix (a buffer, or a parameter when ``learnable``) from now on."""
        check_rank(matrix, 2, "matrix", "(3, C)")
        if matrix.shape[0] != 3:
            raise ValueError(f"matrix: expected shape (3, C), got {tuple(matrix.shape)}")
        check_finite(matrix.detach(), "matrix")
        self._buffers.pop("matrix", None)
        self._parameters.pop("matrix", None)
        if self.learnable:
            self.matrix = nn.Parameter(matrix.detach().clone())
        else:
            self.register_buffer("matrix", matrix.detach().clone())
        self._fit_key = "fixed"
        self.fitted = torch.tensor(False, device=self.fitted.device)
        return self

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # A fitted matrix in a checkpoint fills an unfitted module (its buffers start as None).
        for name in ("matrix", "sensor_white"):
            key = prefix + name
            if key in state_dict and getattr(self, name) is None:
                if name == "matrix":
                    self.set_matrix(state_dict[key])
                else:
                    self.sensor_white = state_dict[key].clone()
        flag = state_dict.get(prefix + "fitted")
        if flag is None:  # a checkpoint from before the flag: given until the next fit tells ("loaded" below)
            state_dict[prefix + "fitted"] = torch.tensor(False)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        if prefix + "matrix" in state_dict:
            # a fitted matrix keeps following the QE, refitted at the next call (taken as given, it stopped following
            # learnable filters after a resume: 0.22 off the uninterrupted run after one filter step); a checkpoint
            # without the flag is told by the next fit (the fit's own matrix, or another: given)
            self._fit_key = (None if self.learnable or (flag is not None and bool(flag))
                             else "loaded" if flag is None else "fixed")

    def fit(self, qe: torch.Tensor, wavelengths_nm) -> SensorToXYZ:
        """Fit the matrix to a sensor's QE (C, L) on ``wavelengths_nm`` (cached per QE and grid).

        A QE that requires grad (learnable filters) while grad is enabled is fitted inside the graph, every call
        (no cache): the matrix and ``sensor_white`` are then functions of the filters (the least-squares fit is
        differentiable, :func:`fit_colour_matrix`), so a loss on the processed image has the filters' total
        derivative, the colour matrix's change included. A ``learnable`` matrix is a parameter of its own: the first
        fit (from the detached QE) makes it, later fits update ``sensor_white`` only (the optimiser trains the
        matrix), and a QE with another number of channels is an error."""
        w = check_wavelengths(torch.as_tensor(wavelengths_nm))
        graph = qe.requires_grad and torch.is_grad_enabled() and not self.learnable
        # the QE's values themselves (its sum alone took a QE with two channels swapped for the same sensor)
        # and the fit's settings (an assigned illuminant 'A' kept the D65 fit)
        key = None if graph else (tuple(qe.shape), qe.detach().double().cpu().numpy().tobytes(),
                                  tuple(w.detach().double().cpu().tolist()), self._settings_key())
        if self._fit_key == "fixed" or key is not None and self._fit_key == key:
            return self
        q = qe.to(torch.float64) if graph else qe.detach().to(torch.float64)
        white = sensor_responses(q, w, self.illuminant, torch.ones(1, w.numel(), dtype=torch.float64))[0]
        white = white / white.amax()
        if self.learnable and isinstance(self.matrix, nn.Parameter):  # the parameter being learned stays
            if self.matrix.shape[1] != q.shape[0]:
                raise ValueError(f"qe: {q.shape[0]} channels, but the learnable matrix being trained is for "
                                 f"{self.matrix.shape[1]}; use a new SensorToXYZ for another sensor")
            self.sensor_white = white.to(device=self.matrix.device, dtype=self.matrix.dtype)
            self._fit_key = key
            return self
        m = sensor_to_xyz_matrix(q, w, self.illuminant, self.surfaces, self.observer, self.white_preserving)
        if self.normalize:
            # The white under the fit's illuminant, at the white level in its brightest channel, -> Y = 1.
            m = m / (m[1] @ white)
        dtype = qe.dtype if qe.is_floating_point() else torch.get_default_dtype()
        m = m.to(device=qe.device, dtype=dtype)
        if self._fit_key == "loaded":  # a loaded matrix: the fit's own (then fitted from now on) or a given one
            loaded = self.matrix.detach()
            if loaded.shape != m.shape or not torch.allclose(m.detach().to(loaded), loaded, rtol=1e-5, atol=1e-8):
                self._fit_key = "fixed"
                self.fitted = torch.tensor(False, device=self.fitted.device)
                return self
        if graph:  # the fitted matrix keeps its graph to the QE (set_matrix would detach it)
            check_finite(m.detach(), "matrix")
            self._parameters.pop("matrix", None)
            self._buffers["matrix"] = m
        else:
            self.set_matrix(m)
        self.sensor_white = white.to(device=qe.device, dtype=dtype)
        self._fit_key = key
        self.fitted = torch.tensor(True, device=self.fitted.device)
        return self

    def _settings_key(self) -> tuple:
        """The fit's settings as a cache key (a spectrum by its values)."""
        def one(v):
            if isinstance(v, torch.Tensor):
                return tuple(v.shape), v.detach().double().cpu().numpy().tobytes()
            return repr(v)
        return tuple(one(v) for v in (self.illuminant, self.surfaces, self.observer, self.white_preserving,
                                      self.normalize))

    def release_graph(self) -> None:
        """Keep the detached values of a matrix fitted inside the graph (:meth:`fit` of a QE that requires grad):
        what was computed with it keeps its graph; the module holds plain tensors again (deepcopy, saving)."""
        for name in ("matrix", "sensor_white"):
            t = self._buffers.get(name)
            if t is not None and t.grad_fn is not None:
                self._buffers[name] = t.detach()

    def forward(self, img: torch.Tensor) -> torch.Tensor:
        if self.matrix is None:
            raise RuntimeError("SensorToXYZ: no matrix yet; pass one or call fit(qe, wavelengths_nm)")
        return _apply_matrix(img, self.matrix)

    def extra_repr(self) -> str:
        return (f"illuminant={self.illuminant!r}, surfaces={self.surfaces!r}, matrix="
                f"{'none' if self.matrix is None else 'fitted' if bool(self.fitted) else 'given'}")


def _display_primaries(display) -> tuple[torch.Tensor, torch.Tensor]:
    """(spd (3, L) energy, wavelengths (L,)) of a display object (duck-typed adapter)."""
    for spd_name in ("primaries_spd", "spd", "primaries_energy", "spectra"):
        spd = getattr(display, spd_name, None)
        if spd is not None:
            break
    w = getattr(display, "wavelengths_nm", None)
    if spd is None or w is None:
        raise TypeError(f"display: expected 'srgb', a (3, 3) RGB->XYZ matrix or an object with primaries' SPDs "
                        f"and wavelengths_nm, got {type(display).__name__}")
    spd = torch.as_tensor(spd)
    return (spd if spd.shape[0] == 3 else spd.T), torch.as_tensor(w)


class ExactConstants(nn.Module):
    """A module whose constant buffers are computed in float64 (a display's matrices, a white's XYZ): a change of
    dtype casts them again from the float64 values, so a module built in float32 and moved to float64 holds the
    float64 constants (``.double()`` kept their float32 roundings: 1.2-2e-7 of a camera's final image). A buffer
    that no longer holds its constant (loaded, assigned or edited) is moved as any buffer is."""

    def register_constant(self, name: str, value: torch.Tensor) -> None:
        """Register buffer ``name`` in torch's default dtype, remembering ``value`` in float64."""
        self.__dict__.setdefault("_constants64", {})[name] = value.detach().to("cpu", torch.float64).clone()
        self.register_buffer(name, value.detach().to(torch.get_default_dtype()))

    def _apply(self, fn, *args, **kwargs):
        # the constants still holding their value (not loaded from a checkpoint, assigned or edited since)
        consts = self.__dict__.get("_constants64", {})
        held = {}
        for name, exact in consts.items():
            b = self._buffers.get(name)
            # compared on the buffer's device (a meta buffer has no values: it is moved as any buffer is)
            if b is not None and b.is_floating_point() and b.shape == exact.shape and not b.is_meta and torch.equal(
                    b.detach(), exact.to(device=b.device, dtype=b.dtype)):
                held[name] = b.dtype
        super()._apply(fn, *args, **kwargs)
        for name, dtype in held.items():
            b = self._buffers.get(name)
            if b is not None and b.dtype != dtype:  # a new dtype: cast from the float64 value, not the rounding
                self._buffers[name] = consts[name].to(device=b.device, dtype=b.dtype)
        return self


class XYZToDisplay(ExactConstants):
    """XYZ -> linear display RGB (3, 3), relative: XYZ with the white at Y = 1 maps to RGB (1, 1, 1) for the
    display's white.

    Args:
        display: ``"srgb"`` (IEC 61966-2-1 matrix, D65 white), a preset name of
            :meth:`isettorch.scene.display.Display.create` (``"lcd"``, ``"crt"``, ``"apple"``), a display object
            with primaries' SPDs, or a (3, 3) RGB -> XYZ matrix (columns = primaries' XYZ).

        adapt_from: None (ISETCam: no adaptation), or the white of the XYZ data (an illuminant name such as
            ``"D65"`` or an XYZ (3,)) to adapt to the display's white with the Bradford transform, so that white
            renders as RGB (1, 1, 1) on a display whose white point differs.

    Buffers: ``matrix`` (XYZ -> RGB, including any adaptation), ``rgb_to_xyz``, ``white_point_xyz`` (3,),
    ``adaptation`` (3, 3; identity without ``adapt_from``), and the attribute ``max_luminance_cd_m2`` (Y of the
    display white, None for sRGB, which is relative).

    Reference: ISETCam ``ieInternal2Display`` (``T = inv(displaySPD' * internalCMF)``); Bradford: Lam (1985),
    as in CIE 159:2004 / ICC.1 Annex E.
    """

    def __init__(self, display="srgb", observer: str = "1931", adapt_from=None) -> None:
        super().__init__()
        self.display = None  # the display object, when one was given (for its transfer function)
        if isinstance(display, str) and display.lower() not in ("srgb", "rec709", "bt709"):
            from ..scene.display import Display, display_names

            if display.lower() not in display_names():
                raise ValueError(f"display: expected 'srgb', one of {display_names()}, a Display or a (3, 3) "
                                 f"matrix, got {display!r}")
            display = Display.create(display.lower())
        if isinstance(display, str):
            inv = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64)
            rgb_to_xyz = torch.linalg.inv(inv)
            max_lum = None
            self.name = "sRGB"
        else:
            if isinstance(display, (list, tuple)) or (hasattr(display, "__array__")
                                                      and not isinstance(display, torch.Tensor)):
                display = as_tensor(display, "display", dtype=torch.float64)  # (a NumPy or list matrix was refused)
            if isinstance(display, torch.Tensor) and display.shape == (3, 3):
                rgb_to_xyz = display.to(torch.float64)
                _check_display_matrix(rgb_to_xyz)
            else:
                spd, w = _display_primaries(display)
                rgb_to_xyz = display_rgb_to_xyz_matrix(spd, w, observer)
                object.__setattr__(self, "display", display)  # not a submodule: only its EOTF is used
            max_lum = float(rgb_to_xyz[1].sum())
            inv = xyz_to_display_matrix(rgb_to_xyz, relative=True)
            self.name = getattr(display, "name", "display")
        self.max_luminance_cd_m2 = max_lum
        white = rgb_to_xyz.sum(1) / rgb_to_xyz[1].sum()
        cat = torch.eye(3, dtype=torch.float64)
        if adapt_from is not None:
            if isinstance(adapt_from, str):
                check_illuminant_name(adapt_from, "adapt_from")  # (the error named cct_k)
                src = white_xyz(adapt_from)
            else:
                src = as_tensor(adapt_from, "adapt_from", dtype=torch.float64)
                if src.numel() != 3 or not bool((src > 0).all()) or not bool(torch.isfinite(src).all()):
                    raise ValueError(f"adapt_from: expected an illuminant name or a white's XYZ (3 positive, finite "
                                     f"values), got {src.reshape(-1).tolist()}")
                src = src.reshape(3)
            cat = bradford_matrix(src, white)
            inv = inv @ cat
        self.register_constant("adaptation", cat)
        self.register_constant("matrix", inv)
        self.register_constant("rgb_to_xyz", rgb_to_xyz)
        self.register_constant("white_point_xyz", white)

    def forward(self, xyz: torch.Tensor) -> torch.Tensor:
        return _apply_matrix(xyz, self.matrix)

    def extra_repr(self) -> str:
        return f"display={self.name!r}, max_luminance_cd_m2={self.max_luminance_cd_m2}"


def _check_display_matrix(rgb_to_xyz: torch.Tensor) -> None:
    """A display's RGB -> XYZ matrix (columns: the primaries' XYZ) is finite, invertible (|det| above 1e-12 of the
    cube of its Frobenius norm, the determinant's scale: three independent primaries) and its white (R = G = B = 1)
    has a positive luminance Y, so XYZ -> RGB exists and the white can be set to Y = 1."""
    check_finite(rgb_to_xyz, "display")
    det = float(torch.linalg.det(rgb_to_xyz))
    norm = float(torch.linalg.matrix_norm(rgb_to_xyz))
    if not abs(det) > 1e-12 * norm ** 3:
        raise ValueError(f"display: the RGB -> XYZ matrix is singular (det {det:.3g}, norm {norm:.3g}): its primaries "
                         f"must be three independent colours, got {rgb_to_xyz.tolist()}")
    if not float(rgb_to_xyz[1].sum()) > 0:
        raise ValueError(f"display: the white (sum of the primaries' Y, row 2) must be positive, got "
                         f"{rgb_to_xyz[1].tolist()}")


class DisplayEncode(nn.Module):
    """Encode linear display RGB for storage: ``"srgb"`` (IEC 61966-2-1), ``"linear"``, a gamma (float) or a
    display object (its ``inverse_eotf``). Values are clipped to [0, 1] first (``clip=True``). With ``clip=False``
    values above 1 keep their headroom (the same curve continues) and, for every encoding but ``"linear"``, values
    below 0, outside the transfer curves' domain, encode as 0 (:func:`~isettorch.image.srgb_encode`'s rule)."""

    def __init__(self, encoding="srgb", clip: bool = True) -> None:
        super().__init__()
        if hasattr(encoding, "inverse_eotf"):  # a display: encode with its own transfer function
            object.__setattr__(self, "display", encoding)
            encoding = "display"
        elif isinstance(encoding, str) and encoding.lower() in ("srgb", "linear"):
            encoding = encoding.lower()  # as display names are, case-insensitive
        elif isinstance(encoding, bool) or not (
                isinstance(encoding, (int, float)) and math.isfinite(encoding) and encoding > 0):
            raise ValueError(f"encoding: expected 'srgb', 'linear', a positive gamma or a display, got {encoding!r}")
        self.encoding = encoding
        self.clip = check_bool(clip, "clip")

    def forward(self, linear: torch.Tensor) -> torch.Tensor:
        x = linear.clamp(0, 1) if self.clip else linear
        if self.encoding == "display":
            return self.display.inverse_eotf(x.clamp_min(0))
        if self.encoding == "srgb":
            return srgb_encode(x, clip=self.clip)
        if self.encoding == "linear":
            return x
        # 0 (and below) encodes as 0: the power of the smallest normal number left 5.7e-18 for gamma 2.2 in float32;
        # the clamp keeps the gradient finite where the power's is not (at 0)
        powered = x.clamp_min(torch.finfo(x.dtype).tiny) ** (1.0 / float(self.encoding))
        return torch.where(x > 0, powered, torch.zeros_like(powered))

    def extra_repr(self) -> str:
        return f"encoding={self.encoding!r}, clip={self.clip}"
