"""Refractive indices of catalogue glasses, looked up in the file's own catalogues (Zemax ``GCAT``).

The catalogue data (Schott, Ohara, Hoya, CDGM, Hikari, Sumita Sellmeier/Cauchy coefficients as published by the
makers) come from the `opticalglass` package (BSD-3, the glass library of `rayoptics`); nothing is hand-written
here. A bare glass name is searched **only** in the catalogues the prescription declares, in the declared order,
so that e.g. ``F2`` in a ``GCAT SCHOTT`` file is Schott's F2 (n_d = 1.62004), never CDGM's F2 (n_d = 1.61293).
Zemax catalogues that opticalglass does not carry (MISC, ZEONEX, INFRARED, ... : plastics, crystals, silica) are
looked up, only when the file declares such a catalogue and only after its maker catalogues, in optiland's
refractiveindex.info material database (optional extra ``lens-reference``; an error names the glass otherwise).
Those data are not OpticStudio's MISC values (PMMA n_d 1.4906 vs 1.4918), so plastic lenses agree to ~1e-3 in
index only.
"""

from __future__ import annotations

import functools

__all__ = ["GlassError", "CATALOGS", "refractive_index", "resolve_glass"]

# Zemax GCAT name -> opticalglass catalogue name
CATALOGS = {"SCHOTT": "Schott", "OHARA": "Ohara", "HOYA": "Hoya", "CDGM": "CDGM", "HIKARI": "Hikari",
            "SUMITA": "Sumita"}
DEFAULT_CATALOGS = ("SCHOTT", "OHARA", "HOYA", "CDGM", "HIKARI", "SUMITA")


class GlassError(ValueError):
    """A glass that cannot be found in the prescription's catalogues."""


def _factory():
    try:
        import opticalglass.glassfactory as gf
    except ImportError as e:  # pragma: no cover - exercised only without the extra
        raise ImportError("lens prescriptions with catalogue glasses need the optional 'lens' extra "
                          "(pip install 'isettorch[lens]', which installs opticalglass)") from e
    return gf


@functools.lru_cache(maxsize=256)
def resolve_glass(name: str, catalogs: tuple[str, ...] = DEFAULT_CATALOGS):
    """The opticalglass glass object for ``name``, searched in ``catalogs`` (Zemax GCAT names) in order.

    Raises:
        GlassError: the name is in none of the catalogues (the message names the glass and the catalogues).
    """
    gf = _factory()
    tried = []
    for cat in catalogs:
        key = CATALOGS.get(cat.upper())
        if key is None:
            tried.append(f"{cat} (catalogue not available)")
            continue
        tried.append(cat)
        try:
            return gf.create_glass(name, key)
        except Exception:  # opticalglass raises GlassNotFoundError (not exported uniformly across versions)
            continue
    others = [c for c in catalogs if c.upper() not in CATALOGS]
    if others:
        g = _optiland_material(name)
        if g is not None:
            return g
        tried.append("optiland database (for " + "/".join(others) + ")")
    raise GlassError(f"glass {name!r}: not found in the prescription's glass catalogues {tried}; expected a "
                     f"glass of one of them (add its catalogue to GCAT, or use a known glass name)")


class _OptilandGlass:
    """Adapter: an optiland material with opticalglass's ``rindex(wavelength_nm)``."""

    def __init__(self, material):
        self.material = material

    def rindex(self, wavelength_nm: float) -> float:
        import numpy as np

        return float(np.asarray(self.material.n(wavelength_nm / 1000.0)).ravel()[0])


def _optiland_material(name: str):
    try:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from optiland.materials import Material

            return _OptilandGlass(Material(name))
    except Exception:  # not installed, or no such material
        return None


@functools.lru_cache(maxsize=4096)
def refractive_index(name: str | None, wavelength_nm: float, catalogs: tuple[str, ...] = DEFAULT_CATALOGS) -> float:
    """Index of refraction (relative to air, as the catalogues give it) of ``name`` at ``wavelength_nm``.

    ``None``/``'AIR'`` is 1 (OpticStudio's convention: indices relative to air at the system temperature).
    """
    if name is None or name.upper() == "AIR":
        return 1.0
    g = resolve_glass(name, tuple(c.upper() for c in catalogs))
    n = float(g.rindex(float(wavelength_nm)))
    if not (n == n) or n < 1.0:
        raise GlassError(f"glass {name!r}: index {n} at {wavelength_nm} nm is outside the catalogue's "
                         f"valid range")
    return n
