"""Sensor designs: a :class:`~isettorch.sensor.filter_bank.FilterBank` and a
:class:`~isettorch.sensor.mosaic.LearnedMosaic` in the library's :class:`~isettorch.sensor.Sensor`.

The fixed designs of the co-design comparison are expressed in the same two modules (fixed filters, fixed mosaic):

* ``bayer_rgb``: ISETCam's default r, g, b filters in a GBRG Bayer cell (Bayer, US patent 3,971,065, 1976);
* ``ycmy``: the complementary c, y, m filters (``'isetcam_cmy'``) in the YC/MY cell of the RGB-against-CMY
  comparison of Farrell, Xiao, Catrysse & Wandell, "A simulation tool for evaluating digital camera image
  quality", SPIE 5294 (2004);
* ``rgbw``: Kodak's "CFA 2.0", 50 % clear (W) pixels in a 4 x 4 cell (Compton & Hamilton, "Image sensor with
  improved light sensitivity", US 2007/0024931), in the layout usually reproduced in the demosaicking literature
  (W on a checkerboard, G on the anti-diagonal, R and B in its corners).

The sensor's own chain does the rest (one simulator): the mosaic's ``mosaic(rates)`` is the sensor's CFA call, so
the photon noise (exact Poisson, straight-through gradient), read noise, auto-exposure and ADC are
:class:`~isettorch.sensor.Sensor`'s.
"""

from __future__ import annotations

from collections.abc import Sequence

from .._checks import SEED_LIMIT, check_seed
from .cfa import CFA
from .filter_bank import FilterBank
from .mosaic import LearnedMosaic
from .sensor import Sensor

__all__ = ["FIXED_DESIGNS", "KODAK_CFA2", "design_sensor", "fixed_design", "learned_design"]

#: Kodak CFA 2.0 (module docstring), rows top to bottom
KODAK_CFA2 = "WBWG/BWGW/WGWR/GWRW"

#: name -> (filters of the bank, cell)
FIXED_DESIGNS: dict[str, tuple[tuple[str, ...], str]] = {
    "bayer_rgb": (("R", "G", "B"), "GBRG"),
    "ycmy": (("C", "Y", "M"), "YCMY"),
    "rgbw": (("R", "G", "B", "W"), KODAK_CFA2),
}


def fixed_design(name: str, **bank_kwargs) -> tuple[FilterBank, LearnedMosaic]:
    """The filter bank and (fixed) mosaic of a design of :data:`FIXED_DESIGNS`.

    Example:
        >>> bank, mosaic = fixed_design("rgbw")
        >>> mosaic.fraction()["W"], mosaic.shape
        (0.5, (4, 4))
    """
    if name not in FIXED_DESIGNS:
        raise ValueError(f"name: unknown fixed design {name!r}; expected one of {sorted(FIXED_DESIGNS)}")
    filters, cell = FIXED_DESIGNS[name]
    bank = FilterBank(filters, learnable=False, **bank_kwargs)
    mosaic = LearnedMosaic(bank.channel_names, pattern=CFA(cell, channel_names=bank.channel_names), learnable=False)
    return bank, mosaic


def learned_design(filters: Sequence[str] = ("learned", "learned", "learned", "W"), shape=(4, 4), *,
                   seed: int = 0, relax: str = "softmax", bank_kwargs: dict | None = None,
                   mosaic_kwargs: dict | None = None) -> tuple[FilterBank, LearnedMosaic]:
    """A learnable bank (``filters``: ``'learned'`` entries and fixed letters) and a learnable ``shape`` mosaic."""
    seed = check_seed(seed)
    bank = FilterBank(filters, seed=seed, **(bank_kwargs or {}))
    # the mosaic's seed is the next one, in [0, 2^64) (2^64 - 1 + 1 overflowed torch's seed, unnamed); kept so (the
    # bank of seed s + 1 draws the same numbers) because the shipped designs were trained from these starts
    mosaic = LearnedMosaic(bank.channel_names, tuple(shape), seed=(seed + 1) % SEED_LIMIT, relax=relax,
                           **(mosaic_kwargs or {}))
    return bank, mosaic


def design_sensor(bank: FilterBank, mosaic: LearnedMosaic | CFA, **sensor_kwargs) -> Sensor:
    """A :class:`Sensor` whose spectral QE is ``bank`` and whose CFA is ``mosaic`` (other arguments: the sensor's).

    The bank's ``ir_filter`` / ``pixel_qe`` complete the QE; ``filters``, ``spectral_qe`` and ``cfa`` cannot be
    given here.
    """
    for key in ("filters", "spectral_qe", "cfa", "learnable_filters"):
        if key in sensor_kwargs:
            raise ValueError(f"{key}: set by the design (bank and mosaic); do not pass it to design_sensor")
    if list(mosaic.channel_names) != list(bank.channel_names):
        raise ValueError(f"mosaic: channel names {mosaic.channel_names} differ from the bank's {bank.channel_names}")
    return Sensor(cfa=mosaic, spectral_qe=bank, **sensor_kwargs)
