"""Filter spectra and the sensor's combined spectral QE (colour filter x IR filter x photodiode QE).

Sets (``filter_set(name)``):

* ``'isetcam_rgb'``: ISETCam's default r, g, b colour filters (``sensorCreate('bayer')``,
  400:10:700 nm, as exported in the ISETCam parity files; ISETCam is MIT-licensed).
* ``'isetcam_cmy'``: a complementary c, y, m set derived from those (C = G + B, Y = R + G,
  M = R + B). ISETCam-like, not ISETCam's own ``cym`` data.
* ``'nikon_5100'``, ``'sigma_sdmerill'``: measured camera sensitivities (NPL) shipped by
  colour-science (``colour.MSDS_CAMERA_SENSITIVITIES``), scaled so the most sensitive channel peaks at 1 (the
  channels keep their measured ratios). The one loader of these data (the training-pair generator uses it).
* ``'clear'``: an unfiltered (W) pixel, 1 everywhere.

:class:`SpectralQE` holds the spectra on their native grid and resamples them once per image
wavelength grid (linear, 0 outside: ISETCam ``interp1(..., 'linear', 0)``), cached; with
``learnable=True`` the filters are ``nn.Parameter`` s kept in [0, 1] through a sigmoid. A per-item QE (one
curve set per batch item, e.g. of :func:`shifted_qe`) holds filters ``[B, C, Ln]`` and gives ``[B, C, L]``; the
:class:`~isettorch.sensor.Sensor` takes it as a per-call ``spectral_qe``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from .. import spectral
from .._checks import (
    as_tensor,
    check_float_dtype,
    check_nanometres,
    check_nonnegative,
    check_wavelengths,
    is_real,
    tensor_version,
)
from .cfa import CFA

__all__ = ["SpectralQE", "filter_set", "filter_set_names", "ir_cut_filter", "photodiode_qe", "shifted_qe"]

_W_ISETCAM = np.arange(400.0, 701.0, 10.0)
# ISETCam default RGB colour filters (sensorCreate 'bayer'), rows r, g, b on 400:10:700 nm.
_ISETCAM_RGB = np.array([
    (0.0140164, 0.0102675, 0.00923432, 0.00917831, 0.00450524, 0.00513995, 0.00889905, 0.00713447, 0.00325176,
     0.00214099, 0.00777862, 0.0146442, 0.029668, 0.040335, 0.0247388, 0.005429, 0.0184696, 0.07857, 0.166173,
     0.25683, 0.321085, 0.355688, 0.370592, 0.373002, 0.373756, 0.37556, 0.374743, 0.381796, 0.379445, 0.383556,
     0.386465),
    (0.00547684, 0.00860536, 0.0151353, 0.0274845, 0.0255677, 0.0148096, 0.0265698, 0.0361583, 0.0156433,
     0.00814119, 0.0605258, 0.159176, 0.255407, 0.322691, 0.347794, 0.340355, 0.308176, 0.249427, 0.184743,
     0.11449, 0.0615279, 0.0244296, 0.00729874, 0.00147736, 0.00192891, 0.00390602, 0.00473499, 0.00421449,
     0.00277486, 0.00179227, 0.00190116),
    (0.00889835, 0.0636692, 0.140264, 0.188636, 0.219425, 0.240199, 0.262235, 0.287592, 0.290768, 0.26705,
     0.216613, 0.142948, 0.0769114, 0.0336076, 0.0106071, 0.00200537, 0.000918868, 0.00126649, 0.00104359,
     0.000575687, 0.000258136, 0.000185377, 0.000181836, 0.000167078, 0.000161256, 0.000216523, 0.000312547,
     0.000380075, 0.000586042, 0.000928747, 0.00162867),
])

_COLOUR_CAMERAS = {"nikon_5100": "Nikon 5100 (NPL)", "sigma_sdmerill": "Sigma SDMerill (NPL)"}

# The set each CFA letter comes from when no set is named (SpectralQE.from_cfa / Sensor with filters=None).
_DEFAULT_SETS = {"R": "isetcam_rgb", "G": "isetcam_rgb", "B": "isetcam_rgb", "C": "isetcam_cmy", "Y": "isetcam_cmy",
                 "M": "isetcam_cmy", "W": "clear"}


def filter_set_names() -> list[str]:
    return ["isetcam_rgb", "isetcam_cmy", *_COLOUR_CAMERAS, "clear"]


@functools.cache
def _filter_set_np(name: str) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    if name == "isetcam_rgb":
        return _W_ISETCAM, _ISETCAM_RGB, ("R", "G", "B")
    if name == "isetcam_cmy":
        r, g, b = _ISETCAM_RGB
        return _W_ISETCAM, np.stack([g + b, r + g, r + b]), ("C", "Y", "M")
    if name in _COLOUR_CAMERAS:
        import colour

        m = colour.MSDS_CAMERA_SENSITIVITIES[_COLOUR_CAMERAS[name]]
        vals = np.asarray(m.values, float).T
        # one normalisation: the most sensitive channel peaks at 1, the others keep their ratio to it (the ratios
        # set a camera's raw white balance and per-channel noise); colour-science ships the NPL sets with every
        # channel at peak 1 already, so on these data it equals a per-channel normalisation
        return np.asarray(m.wavelengths, float), vals / vals.max(), ("R", "G", "B")
    if name == "clear":
        return np.array([300.0, 1100.0]), np.ones((1, 2)), ("W",)
    raise ValueError(f"name: unknown filter set {name!r}; expected one of {filter_set_names()}")


def filter_set(name: str, wavelengths_nm=None, *, dtype=None, device=None):
    """A named set of filter spectra: ``(wavelengths [Ln], spectra [C, Ln], letters)``.

    With ``wavelengths_nm`` the spectra are resampled onto that grid (linear, 0 outside).
    """
    if dtype is not None:  # (an integer dtype truncated the spectra to 0)
        check_float_dtype(dtype)
    w, v, letters = _filter_set_np(str(name).lower())
    wt = torch.tensor(w, dtype=torch.float64)
    vt = torch.tensor(v, dtype=torch.float64)
    if wavelengths_nm is not None:
        dst = check_wavelengths(torch.as_tensor(wavelengths_nm)).to(torch.float64).cpu()
        vt = spectral.resample(vt, wt, dst)
        wt = dst
    dtype = dtype or torch.get_default_dtype()
    return wt.to(dtype=dtype, device=device), vt.to(dtype=dtype, device=device), letters


def ir_cut_filter(wavelengths_nm, cutoff_nm: float = 650.0, edge_width_nm: float = 10.0, *, dtype=None,
                  device=None) -> torch.Tensor:
    """A smooth IR-cut (short-pass) filter [L]: ``1 / (1 + exp((lambda - cutoff) / width))``.

    A logistic edge, transmitting 0.5 at ``cutoff_nm``; a common model of a dichroic hot mirror.
    """
    if not edge_width_nm > 0:
        raise ValueError(f"edge_width_nm: expected a positive width, got {edge_width_nm}")
    w = check_wavelengths(torch.as_tensor(wavelengths_nm)).to(torch.float64)
    out = torch.sigmoid(-(w - cutoff_nm) / edge_width_nm)
    return out.to(dtype=check_float_dtype(dtype or torch.get_default_dtype()), device=device)


def photodiode_qe(wavelengths_nm, value: float = 1.0, *, dtype=None, device=None) -> torch.Tensor:
    """Photodiode QE [L]: a constant (ISETCam's default pixel QE is 1 at every wavelength)."""
    if not (is_real(value) and 0 <= value <= 1):  # (True was a QE of 1)
        raise ValueError(f"value: expected a quantum efficiency in [0, 1], got {value!r}")
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    return torch.full((w.numel(),), float(value), dtype=check_float_dtype(dtype or torch.get_default_dtype()),
                      device=device)


def _logit(x: torch.Tensor, floor: float = 1e-8) -> torch.Tensor:
    """The inverse of the sigmoid, of ``x`` held in [floor, 1 - floor]."""
    x = x.clamp(floor, 1 - floor)
    return torch.log(x) - torch.log1p(-x)


class SpectralQE(nn.Module):
    """Combined spectral QE ``[C, L]`` = colour filters x IR filter x photodiode QE.

    Args:
        filters: ``[C, Ln]`` transmittances on ``wavelengths_nm`` (in [0, 1]), or ``[B, C, Ln]`` for a per-item
            QE (one set of curves per batch item; the QE is then ``[B, C, L]``).
        wavelengths_nm: native grid ``[Ln]`` (nm).
        channel_names: C names (CFA letters such as 'R', 'G', 'B').
        ir_filter, pixel_qe: optional ``[Ln]`` spectra on the same grid (default 1).
        learnable: make the filters ``nn.Parameter`` s, kept in [0, 1] by a sigmoid (a filter that can be made at
            every step, DESIGN.md; a softplus had let 50 Adam steps take a 0.9 filter to 5.7). Values start within
            [1e-8, 1 - 1e-8], where the sigmoid's slope (the parameter's gradient factor) is about 1e-8: an entry
            that starts at 0 or 1 barely moves under plain SGD (Adam rescales its step). Start learnable filters
            inside (0, 1), or use :class:`~isettorch.sensor.FilterBank` (smooth bands through a sigmoid).

    Example:
        >>> qe = SpectralQE.from_cfa(CFA('GBRG'))
        >>> qe(torch.arange(400., 701., 10.)).shape
        torch.Size([3, 31])
    """

    def __init__(self, filters, wavelengths_nm, channel_names: Sequence[str], *, ir_filter=None, pixel_qe=None,
                 learnable: bool = False) -> None:
        super().__init__()
        w = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm", dtype=torch.float64))
        f = as_tensor(filters, "filters", dtype=torch.float64)
        if f.dim() == 1:
            f = f[None]
        if f.dim() not in (2, 3) or f.shape[-1] != w.numel():
            raise ValueError(f"filters: expected shape [C, {w.numel()}] (or [B, C, {w.numel()}] per item) to match "
                             f"wavelengths_nm, got {tuple(f.shape)}")
        check_nonnegative(f, "filters")
        if float(f.max()) > 1 + 1e-9:  # (as ir_filter and pixel_qe: a filter of 3 read three times the electrons)
            raise ValueError(f"filters: expected transmittances in [0, 1] at every wavelength, got a maximum of "
                             f"{float(f.max()):.6g}")
        if len(channel_names) != f.shape[-2]:
            raise ValueError(f"channel_names: expected {f.shape[-2]} names, got {list(channel_names)}")
        extra = torch.ones_like(w)
        for label, spd in (("ir_filter", ir_filter), ("pixel_qe", pixel_qe)):
            if spd is not None:
                s = as_tensor(spd, label, dtype=torch.float64).reshape(-1)
                if s.numel() != w.numel():
                    raise ValueError(f"{label}: expected {w.numel()} values on wavelengths_nm, got {s.numel()}")
                check_nonnegative(s, label)
                if float(s.max()) > 1 + 1e-9:  # (a design file's QE x 3 read three times the electrons)
                    raise ValueError(f"{label}: expected a fraction in [0, 1] at every wavelength (a transmittance "
                                     f"or quantum efficiency), got a maximum of {float(s.max()):.6g}")
                extra = extra * s
        self.channel_names = list(channel_names)
        self.learnable = bool(learnable)
        self.register_buffer("wavelengths_nm", w)
        self.register_buffer("extra", extra)
        if learnable:
            self.raw_filters = nn.Parameter(_logit(f))
        else:
            self.register_buffer("fixed_filters", f)
        self._cache: dict = {}

    @classmethod
    def from_cfa(cls, cfa: CFA, filters: str | dict | None = None, *, ir_filter=None, pixel_qe=None,
                 learnable: bool = False, wavelengths_nm=None) -> SpectralQE:
        """Filters for each CFA channel, looked up by letter in a named set.

        ``filters``: None (default) takes each letter from the library's sets, R, G, B from ``'isetcam_rgb'``,
        C, Y, M from ``'isetcam_cmy'`` and W from ``'clear'``; a set name (:func:`filter_set_names`) takes every
        letter from that set, and a letter the set lacks is an error (``'nikon_5100'`` has no C: no other set's
        curve is put in its place); a dict ``{channel_name: (wavelengths [Ln], spectrum [Ln])}`` gives user spectra.
        ``ir_filter``/``pixel_qe`` are given on ``wavelengths_nm`` (default 400:10:700).
        """
        grid = torch.tensor(_W_ISETCAM) if wavelengths_nm is None else torch.as_tensor(wavelengths_nm,
                                                                                        dtype=torch.float64)
        rows = []
        for name in cfa.channel_names:
            if isinstance(filters, dict):
                if name not in filters:
                    raise ValueError(f"filters: no spectrum for CFA channel {name!r}; got keys {sorted(filters)}")
                w_src, s_src = filters[name]
                w_src = torch.as_tensor(w_src, dtype=torch.float64)
                # (wavelengths in um or m had resampled to an all-zero filter on the nm grid: a black channel)
                check_nanometres(w_src, f"filters[{name!r}] wavelengths")
                row = spectral.resample(torch.as_tensor(s_src, dtype=torch.float64), w_src, grid)
                if not bool((row != 0).any()) and bool((torch.as_tensor(s_src) != 0).any()):
                    raise ValueError(f"filters[{name!r}]: its {float(w_src.min()):g}-{float(w_src.max()):g} nm miss "
                                     f"the sensor's grid ({float(grid.min()):g}-{float(grid.max()):g} nm): the "
                                     f"channel would be black; expected a spectrum over the grid")
                rows.append(row)
                continue
            set_name = filters if filters is not None else _DEFAULT_SETS.get(name)
            defaults = "R, G, B from 'isetcam_rgb'; C, Y, M from 'isetcam_cmy'; W from 'clear'"
            if set_name is None:
                raise ValueError(f"filters: the library's default sets have no filter for CFA channel {name!r} "
                                 f"({defaults}); pass a dict of user spectra")
            _, vals, letters = filter_set(set_name, grid, dtype=torch.float64)
            if name not in letters:
                raise ValueError(f"filters: the set {filters!r} has no filter for CFA channel {name!r} (its filters: "
                                 f"{list(letters)}); leave filters out for the library's default per letter "
                                 f"({defaults}), or pass a dict of user spectra")
            rows.append(vals[letters.index(name)])
        return cls(torch.stack(rows), grid, cfa.channel_names, ir_filter=ir_filter, pixel_qe=pixel_qe,
                   learnable=learnable)

    @property
    def filters(self) -> torch.Tensor:
        """Colour filter transmittances on the native grid ``[C, Ln]``."""
        if self.learnable:
            return torch.sigmoid(self.raw_filters)
        return self.fixed_filters

    @property
    def num_channels(self) -> int:
        return len(self.channel_names)

    @property
    def batch_size(self) -> int | None:
        """B for a per-item QE (filters ``[B, C, Ln]``), None for one QE shared by every item."""
        f = self.raw_filters if self.learnable else self.fixed_filters
        return f.shape[0] if f.dim() == 3 else None

    @property
    def cacheable(self) -> bool:
        """Whether a resampled QE may be reused across calls: fixed filters that carry no graph (a tensor that
        requires grad, given with ``learnable=False``, must be evaluated per call: a cached result kept the first
        call's graph, so a second backward failed)."""
        return not (self.learnable or self.fixed_filters.requires_grad or self.extra.requires_grad)

    def cache_state(self) -> tuple[tuple, tuple]:
        """``(token, tensors)``: the identity and version of every tensor the QE is made of (filters, the IR filter
        and pixel QE, the native grid) and those tensors. A cache keyed on the token and holding the tensors (so
        their ids are not reused) sees a new tensor assigned to any of them and any in-place edit."""
        f = self._buffers["fixed_filters"] if "fixed_filters" in self._buffers else self.raw_filters
        tensors = (f, self.extra, self.wavelengths_nm)
        return tuple((id(t), tensor_version(t)) for t in tensors), tensors

    def native(self) -> torch.Tensor:
        """Combined QE on the native grid ``[C, Ln]`` (``[B, C, Ln]`` per item)."""
        return self.filters * self.extra

    def forward(self, wavelengths_nm: torch.Tensor, *, dtype=None, device=None) -> torch.Tensor:
        """Combined QE on ``wavelengths_nm`` ``[C, L]`` (``[B, C, L]`` per item; resampled once per grid; cached unless
        learnable)."""
        w = torch.as_tensor(wavelengths_nm)
        if w.dim() == 0:
            w = w.reshape(1)
        dtype = dtype or (w.dtype if w.is_floating_point() else torch.get_default_dtype())
        device = device or w.device
        if self.learnable:
            w = self._check_overlap(check_wavelengths(w))
            return spectral.resample(self.native(), self.wavelengths_nm, w.to(self.wavelengths_nm.device)).to(
                dtype=dtype, device=device)
        # a grid found in the cache was validated when its entry was made: checked on a miss only. The key holds the
        # QE's tensors' identity and version (cache_state: a new tensor or an in-place edit is a miss)
        token, tensors = self.cache_state()
        key = (tuple(w.tolist()) if w.dim() == 1 and self.cacheable else None, dtype, str(device), token)
        hit = self._cache.get(key) if key[0] is not None else None
        if hit is not None and all(a is b for a, b in zip(hit[0], tensors)):
            return hit[1]
        w = self._check_overlap(check_wavelengths(w))
        if len(self._cache) > 16:
            self._cache.clear()
        out = spectral.resample(self.native(), self.wavelengths_nm, w.to(self.wavelengths_nm.device, torch.float64))
        out = out.to(dtype=dtype, device=device)
        if key[0] is not None:
            self._cache[key] = (tensors, out)
        return out

    def _check_overlap(self, w: torch.Tensor) -> torch.Tensor:
        """``w``, or a ValueError when it misses the filters' wavelengths entirely: QE is 0 outside them (ISETCam's
        interpolation with 0 extrapolation), so such an image would read black without a word."""
        lo, hi = float(self.wavelengths_nm[0]), float(self.wavelengths_nm[-1])
        if float(w.max()) < lo or float(w.min()) > hi:
            raise ValueError(f"wavelengths_nm: the image's {float(w.min()):g}-{float(w.max()):g} nm miss the sensor's "
                             f"spectral QE ({lo:g}-{hi:g} nm) entirely: every pixel would read black; render the "
                             f"scene on a grid that the filters cover or give the sensor filters for these bands")
        return w

    def _apply(self, fn, *args, **kwargs):
        self._cache = {}
        return super()._apply(fn, *args, **kwargs)


def shifted_qe(cfa: CFA, filters: str = "nikon_5100", shift_nm=0.0) -> SpectralQE:
    """The QE of a named filter set for ``cfa``'s channels with each channel's curve translated along the wavelength
    axis, ``QE'_c(lambda) = QE_c(lambda - shift_c)`` (a model of the spread of a sensor's spectral sensitivities),
    on the set's native grid (linear, 0 outside the shifted support: ISETCam ``interp1(..., 'linear', 0)``).

    Args:
        cfa: the CFA (its channel letters pick the set's curves).
        filters: a filter set name (:func:`filter_set_names`; its curves keep the set's scaling, e.g. the NPL
            camera sets peak at 1).
        shift_nm: shifts in nm: a number (every channel), ``[C]`` (one QE) or ``[B, C]`` (a per-item QE, filters
            ``[B, C, Ln]``), on any device.

    Example:
        >>> qe = shifted_qe(CFA("RGGB"), "nikon_5100", torch.tensor([[5.0, 0.0, -5.0], [0.0, 0.0, 0.0]]))
        >>> qe.batch_size, tuple(qe(torch.arange(400., 701., 10.)).shape)
        (2, (2, 3, 31))
    """
    if not isinstance(cfa, CFA):
        raise TypeError(f"cfa: expected a CFA, got {type(cfa).__name__}")
    s = torch.as_tensor(shift_nm, dtype=torch.float64)
    n_c = len(cfa.channel_names)
    if s.dim() == 0:
        s = s.expand(n_c)
    if s.dim() not in (1, 2) or s.shape[-1] != n_c:
        raise ValueError(f"shift_nm: expected a number, [{n_c}] or [B, {n_c}] shifts (one per CFA channel "
                         f"{cfa.channel_names}), got shape {tuple(s.shape)}")
    if not bool(torch.isfinite(s).all()):
        raise ValueError("shift_nm: expected finite shifts (nm)")
    w, vals, letters = filter_set(filters, dtype=torch.float64, device=s.device)
    missing = [c for c in cfa.channel_names if c not in letters]
    if missing:
        raise ValueError(f"filters: the set {filters!r} has no curve for CFA channel {missing[0]!r} "
                         f"(its channels: {letters})")
    rows = vals[[letters.index(c) for c in cfa.channel_names]]  # [C, Ln]
    # the curve sampled at (w + shift) resampled onto w, per channel (and item)
    out = spectral.resample_rows(rows.expand(*s.shape, -1), w + s[..., None], w)
    return SpectralQE(out, w, cfa.channel_names)

