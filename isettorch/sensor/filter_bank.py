"""A bank of K colour-filter transmittances that can be manufactured, some learned, some fixed.

Learned filters are smooth by construction (DESIGN.md: "a transmittance is a sigmoid or a non-negative mixture,
never clipped afterwards"):

    T(l) = sigmoid(b + sum_j a_j phi_j(l)),   a_j = A tanh(u_j),   b = A tanh(v)

with ``phi_j`` raised-cosine (Hann) bands of half-width ``w`` centred every ``w`` nm, which sum to 1 (a partition
of unity), so ``T`` lies in (0, 1) at every wavelength. Between two band centres only two bands overlap and
``phi_j' = -phi_{j+1}'``, so ``|s'| <= (pi / 2w) |a_j - a_{j+1}| <= pi A / w`` and, with ``sigmoid' <= 1/4``,

    ``|dT/dl| <= pi A / (4 w)``   per nm                                                    (:func:`max_slope_per_nm`)

The defaults (``A = 3``, ``w = 50 nm``) give 0.047 / nm, under :data:`MAX_SLOPE_PER_NM` = 0.05 / nm: a 10-90 %
edge no narrower than about 22 nm. Manufactured colour filters are not steeper: colour-science's measured camera
sensitivities (NPL, Nikon 5100 and Sigma SDMerill, normalised to peak 1) reach 0.059 and 0.074 / nm, ISETCam's
default r, g, b filters 0.0099 / nm; absorptive pigment and dye CFA filters have edges tens of nm wide.

Fixed filters are the library's (:func:`isettorch.sensor.filters.filter_set`): R, G, B (``'isetcam_rgb'``),
C, Y, M (``'isetcam_cmy'``) and W (``'clear'``, 1 at every wavelength). ISETCam's r, g, b tables peak at 0.39,
0.35 and 0.29; with ``fixed_scale='peak'`` each set is divided by its largest value (its most transmissive channel
peaks at 1, the channels keep their ratios, as :func:`~isettorch.sensor.filters.filter_set` does for the measured
camera sets), so fixed and learned filters can transmit as much and a clear pixel collects about 4.2 times the
D65 photons of a green one in the design camera (11 times with the raw tables).

References: learned filter responses trained with the reconstruction network, Nie, Gu, Zheng, Lam, Sato & Sato,
"Deeply learned filter response functions for hyperspectral reconstruction", CVPR 2018; learned colour filter
arrays, Chakrabarti, "Learning sensor multiplexing design through back-propagation", NeurIPS 2016; Henz, Gastal &
Oliveira, "Deep joint design of color filter arrays and demosaicing", Eurographics 2018.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from .._checks import check_bool, check_nanometres, check_seed, tensor_version
from .filters import _W_ISETCAM, SpectralQE, filter_set

__all__ = ["FIXED_FILTERS", "MAX_SLOPE_PER_NM", "FilterBank", "check_manufacturable", "max_slope_per_nm",
           "raised_cosine_bands",
           "smooth_band_transmittance"]

#: the steepest transmittance slope (per nm) a design may have (module docstring)
MAX_SLOPE_PER_NM = 0.05

#: fixed filters by letter: the library set that holds each
FIXED_FILTERS = {"R": "isetcam_rgb", "G": "isetcam_rgb", "B": "isetcam_rgb", "C": "isetcam_cmy",
                 "Y": "isetcam_cmy", "M": "isetcam_cmy", "W": "clear"}


def raised_cosine_bands(wavelengths_nm: torch.Tensor, centres_nm: torch.Tensor, half_width_nm: float
                        ) -> torch.Tensor:
    """Raised-cosine (Hann) bands ``[J, L]``: ``cos^2(pi (l - c_j) / (2 w))`` for ``|l - c_j| < w``, else 0.

    With centres every ``w`` nm the bands sum to 1 between the first and the last centre (partition of unity).
    """
    d = (wavelengths_nm[None, :] - centres_nm[:, None]) / half_width_nm
    return torch.where(d.abs() < 1, torch.cos(0.5 * math.pi * d) ** 2, torch.zeros_like(d))


def smooth_band_transmittance(amplitudes: torch.Tensor, offsets: torch.Tensor, bands: torch.Tensor) -> torch.Tensor:
    """``sigmoid(offset + amplitudes @ bands)``: ``amplitudes [N, J]``, ``offsets [N]``, ``bands [J, L]`` -> ``[N, L]``
    in (0, 1)."""
    return torch.sigmoid(offsets[:, None] + amplitudes @ bands)


def max_slope_per_nm(max_log_odds: float, band_width_nm: float) -> float:
    """The bound ``pi A / (4 w)`` on ``|dT/dl|`` of a learned filter (module docstring)."""
    if not (math.isfinite(band_width_nm) and band_width_nm > 0):
        raise ValueError(f"band_width_nm: expected a positive band width (nm), got {band_width_nm!r}")
    return math.pi * max_log_odds / (4 * band_width_nm)


def check_manufacturable(filters: torch.Tensor, wavelengths_nm: torch.Tensor, name: str = "filters") -> None:
    """ValueError naming ``name`` unless the transmittances ``[K, L]`` are finite, in [0, 1], and no steeper than
    :data:`MAX_SLOPE_PER_NM` between neighbouring samples of ``wavelengths_nm``."""
    f = torch.as_tensor(filters, dtype=torch.float64)
    w = torch.as_tensor(wavelengths_nm, dtype=torch.float64).reshape(-1)
    if f.dim() != 2 or f.shape[0] == 0 or f.shape[1] != w.numel():
        raise ValueError(f"{name}: expected transmittances [K >= 1, L = {w.numel()}] (one row per filter on "
                         f"wavelengths_nm), got shape {tuple(f.shape)}")
    if w.numel() > 1 and not bool((w[1:] > w[:-1]).all()):
        raise ValueError(f"{name}: expected strictly increasing wavelengths_nm, got {w.tolist()}")
    if not bool(torch.isfinite(f).all()):
        raise ValueError(f"{name}: expected finite transmittances")
    if float(f.min()) < 0 or float(f.max()) > 1:
        raise ValueError(f"{name}: expected transmittances in [0, 1], got [{float(f.min()):.6g}, {float(f.max()):.6g}]")
    if w.numel() > 1:
        slope = float(((f[:, 1:] - f[:, :-1]) / (w[1:] - w[:-1])).abs().max())
        if slope > MAX_SLOPE_PER_NM + 1e-12:
            raise ValueError(f"{name}: a transmittance changes by {slope:.4g} per nm, steeper than the "
                             f"manufacturable {MAX_SLOPE_PER_NM} per nm")


class FilterBank(SpectralQE):
    """K filters, learned (smooth bands through a sigmoid) or fixed (the library's R, G, B, C, Y, M, W), as the
    sensor's :class:`~isettorch.sensor.filters.SpectralQE` (combined with ``ir_filter`` and ``pixel_qe``).

    Args:
        filters: K entries, each a fixed letter of :data:`FIXED_FILTERS` or ``'learned'``.
        wavelengths_nm: the native grid (default 400:10:700); learned filters are sampled on it and resampled
            to a scene's grid linearly, like every library filter.
        band_width_nm: band spacing and half-width ``w``; max_log_odds: ``A`` (module docstring).
        learnable: False freezes the learned filters (their parameters get ``requires_grad=False``).
        ir_filter, pixel_qe: as in :class:`SpectralQE`.
        names: channel names (default: the letter of a fixed filter, ``F<i>`` for the i-th learned one).
        seed: the initial learned filters' small perturbation (their bands start as band-pass filters spaced
            evenly over the grid).
        fixed_scale: ``'table'`` (the library's values) or ``'peak'`` (each set divided by its maximum; module
            docstring).

    Example:
        >>> bank = FilterBank(["learned", "learned", "learned", "W"])
        >>> bank.channel_names, tuple(bank(torch.arange(400., 701., 10.)).shape)
        (['F0', 'F1', 'F2', 'W'], (4, 31))
    """

    def __init__(self, filters: Sequence[str], wavelengths_nm=None, *, band_width_nm: float = 50.0,
                 max_log_odds: float = 3.0, learnable: bool = True, ir_filter=None, pixel_qe=None,
                 names: Sequence[str] | None = None, seed: int = 0, fixed_scale: str = "table") -> None:
        spec = [str(f) for f in filters]
        if not spec:
            raise ValueError("filters: expected at least one filter")
        bad = [f for f in spec if f != "learned" and f not in FIXED_FILTERS]
        if bad:
            raise ValueError(f"filters: unknown filter {bad[0]!r}; expected 'learned' or one of "
                             f"{sorted(FIXED_FILTERS)}")
        check_bool(learnable, "learnable")
        if fixed_scale not in ("table", "peak"):
            raise ValueError(f"fixed_scale: expected 'table' or 'peak', got {fixed_scale!r}")
        if not (band_width_nm > 0 and math.isfinite(band_width_nm)):
            raise ValueError(f"band_width_nm: expected a positive width, got {band_width_nm!r}")
        if not (max_log_odds > 0 and math.isfinite(max_log_odds)):
            raise ValueError(f"max_log_odds: expected a positive value, got {max_log_odds!r}")
        grid = torch.tensor(_W_ISETCAM) if wavelengths_nm is None else torch.as_tensor(wavelengths_nm,
                                                                                        dtype=torch.float64)
        step = float((grid[1:] - grid[:-1]).min()) if grid.numel() > 1 else 0.0
        if "learned" in spec and band_width_nm < step:
            raise ValueError(f"band_width_nm: expected at least the wavelength grid's step ({step:g} nm; a narrower "
                             f"band falls between samples), got {band_width_nm!r}")
        if "learned" in spec and max_slope_per_nm(max_log_odds, band_width_nm) > MAX_SLOPE_PER_NM:
            # manufacturable by construction at every step (a steeper bound was found only when the design was saved)
            raise ValueError(f"band_width_nm, max_log_odds: the learned filters' slope bound pi A / (4 w) = "
                             f"{max_slope_per_nm(max_log_odds, band_width_nm):.4g} per nm (A = {max_log_odds:g}, "
                             f"w = {band_width_nm:g} nm) exceeds the manufacturable {MAX_SLOPE_PER_NM} per nm; "
                             f"widen the bands or lower max_log_odds")
        learned_idx = [i for i, f in enumerate(spec) if f == "learned"]
        if names is None:
            names = [f if f != "learned" else f"F{learned_idx.index(i)}" for i, f in enumerate(spec)]
        names = [str(n) for n in names]
        if len(names) != len(spec) or len(set(names)) != len(names):
            raise ValueError(f"names: expected {len(spec)} unique names, got {names}")
        rows = []
        for f in spec:
            if f == "learned":
                rows.append(torch.zeros_like(grid))
            else:
                _, vals, letters = filter_set(FIXED_FILTERS[f], grid, dtype=torch.float64)
                if fixed_scale == "peak":
                    vals = vals / vals.max()
                rows.append(vals[letters.index(f)])
        super().__init__(torch.stack(rows), grid, names, ir_filter=ir_filter, pixel_qe=pixel_qe, learnable=False)
        self.spec = spec
        self.fixed_scale = fixed_scale
        self.band_width_nm = float(band_width_nm)
        self.max_log_odds = float(max_log_odds)
        lo, hi = float(grid.min()), float(grid.max())
        n_bands = max(2, math.ceil((hi - lo) / band_width_nm) + 1)
        if n_bands > 10_000:  # (a band per 0.03 nm over 300 nm: far finer than any grid; 1e-6 nm asked for 74 GB)
            raise ValueError(f"band_width_nm: {band_width_nm!r} gives {n_bands} bands over {lo:g}-{hi:g} nm; "
                             f"expected at most 10000")
        centres = lo + band_width_nm * torch.arange(n_bands, dtype=torch.float64)
        self.register_buffer("band_centres_nm", centres)
        self.register_buffer("learned_index", torch.tensor(learned_idx, dtype=torch.long))
        n = len(learned_idx)
        self.raw_amplitudes = nn.Parameter(self._initial_raw(n, centres, seed), requires_grad=learnable and n > 0)
        self.raw_offsets = nn.Parameter(torch.zeros(n, dtype=torch.float64), requires_grad=learnable and n > 0)
        self.learnable = learnable and n > 0

    @classmethod
    def from_table(cls, filters, wavelengths_nm, names: Sequence[str], *, pixel_qe=None) -> FilterBank:
        """A fixed bank of tabulated transmittances ``[K, L]`` on ``wavelengths_nm`` (e.g. a design file's exported
        filters). ValueError unless every value is in [0, 1] and the slopes are within :data:`MAX_SLOPE_PER_NM`
        (:func:`check_manufacturable`); ``pixel_qe`` ``[L]``: the rest of the QE (IR filter x photodiode)."""
        f = torch.as_tensor(filters, dtype=torch.float64)
        w = torch.as_tensor(wavelengths_nm, dtype=torch.float64)
        if f.dim() != 2 or f.shape[1] != w.numel():
            raise ValueError(f"filters: expected shape [K, {w.numel()}] to match wavelengths_nm, got {tuple(f.shape)}")
        check_nanometres(w, "wavelengths_nm")  # (a table in um had been refused only at first use, misleadingly)
        check_manufacturable(f, w, "filters")
        bank = cls(["W"] * f.shape[0], w, learnable=False, names=names, pixel_qe=pixel_qe)
        with torch.no_grad():
            bank.fixed_filters.copy_(f)
        bank.spec = ["table"] * f.shape[0]
        return bank

    def _initial_raw(self, n: int, centres: torch.Tensor, seed: int) -> torch.Tensor:
        """Band-pass starts: filter i peaks near the i-th of n evenly spaced wavelengths (+ a seeded perturbation)."""
        if n == 0:
            return torch.zeros(0, centres.numel(), dtype=torch.float64)
        lo, hi = float(self.wavelengths_nm.min()), float(self.wavelengths_nm.max())
        peaks = lo + (torch.arange(n, dtype=torch.float64) + 0.5) * (hi - lo) / n
        shape = 2 * torch.exp(-((centres[None] - peaks[:, None]) / (0.6 * (hi - lo) / n + 1e-9)) ** 2) - 1
        g = torch.Generator().manual_seed(check_seed(seed))  # (int() took 1.5, True and "3")
        raw = 0.8 * shape + 0.1 * torch.randn(n, centres.numel(), generator=g, dtype=torch.float64)
        return torch.atanh(raw.clamp(-0.95, 0.95))

    @property
    def learnable(self) -> bool:
        """Whether the bank has learned filters still learning (a flag, not the parameters' ``requires_grad``:
        read by :meth:`Sensor.spectral_weights`, a learnable bank is never cached)."""
        return self.__dict__.get("_learnable", False)

    @learnable.setter
    def learnable(self, value) -> None:  # SpectralQE.__init__ sets it to False; the bank sets it after
        self.__dict__["_learnable"] = bool(value)

    @property
    def num_learned(self) -> int:
        return int(self.learned_index.numel())

    def bands(self, wavelengths_nm: torch.Tensor | None = None) -> torch.Tensor:
        """The raised-cosine bands ``[J, L]`` on ``wavelengths_nm`` (default: the native grid)."""
        w = self.wavelengths_nm if wavelengths_nm is None else torch.as_tensor(wavelengths_nm, dtype=torch.float64)
        return raised_cosine_bands(w.to(self.band_centres_nm), self.band_centres_nm, self.band_width_nm)

    def learned_transmittance(self, wavelengths_nm: torch.Tensor | None = None) -> torch.Tensor:
        """The learned filters ``[N, L]`` evaluated analytically on ``wavelengths_nm`` (default: the native grid)."""
        a = self.max_log_odds * torch.tanh(self.raw_amplitudes)
        b = self.max_log_odds * torch.tanh(self.raw_offsets)
        return smooth_band_transmittance(a, b, self.bands(wavelengths_nm).to(a.dtype))

    @property
    def filters(self) -> torch.Tensor:
        """Transmittances on the native grid ``[K, Ln]``, each in [0, 1]."""
        if self.num_learned == 0:
            return self.fixed_filters
        learned = self.learned_transmittance().to(self.fixed_filters.dtype)
        return self.fixed_filters.index_copy(0, self.learned_index, learned)

    @property
    def max_slope_bound_per_nm(self) -> float:
        """The construction's bound on ``|dT/dl|`` of the learned filters (:func:`max_slope_per_nm`)."""
        return max_slope_per_nm(self.max_log_odds, self.band_width_nm)

    def forward(self, wavelengths_nm: torch.Tensor, *, dtype=None, device=None) -> torch.Tensor:
        if self.learnable:
            return super().forward(wavelengths_nm, dtype=dtype, device=device)
        # fixed (or frozen) bank: the parent's cache, keyed on the fixed filters' version; frozen learned rows are
        # written into them whenever their parameters changed (an optimiser step, load_state_dict)
        if self.num_learned:
            amp, off = self.raw_amplitudes, self.raw_offsets
            key = self.__dict__.get("_written_key")
            versions = (tensor_version(amp), tensor_version(off))
            if key is None or key[0] is not amp or key[1] is not off or key[2:] != versions:
                with torch.no_grad():
                    self.fixed_filters.copy_(self.filters)
                self._written_key = (amp, off, *versions)
        return super().forward(wavelengths_nm, dtype=dtype, device=device)

    def cache_state(self) -> tuple[tuple, tuple]:
        """:meth:`SpectralQE.cache_state` with the learned rows' parameters (a frozen bank writes them into the fixed
        filters when its forward runs: a cache read before it saw the old rows after a change of the parameters)."""
        token, tensors = super().cache_state()
        extra = (self.raw_amplitudes, self.raw_offsets)
        return token + tuple((id(t), tensor_version(t)) for t in extra), tensors + extra

    def freeze(self) -> FilterBank:
        """Stop learning: the filters become fixed at their current values (returns self)."""
        self.raw_amplitudes.requires_grad_(False)
        self.raw_offsets.requires_grad_(False)
        self.learnable = False
        self.__dict__.pop("_written_key", None)
        return self

    def extra_repr(self) -> str:
        return (f"filters={self.spec}, names={self.channel_names}, band_width_nm={self.band_width_nm:g}, "
                f"max_log_odds={self.max_log_odds:g}")
