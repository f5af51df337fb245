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

Valid wavelength range (:func:`valid_range_nm`): a maker's dispersion formula is fitted to the refractive indices
its catalogue tabulates and holds between the shortest and the longest of them ("for some glass types, not all
refractive indices in the standard spectral range are listed on the data sheet. In such cases, the applicable
scope of this dispersion formula is limited to the given refractive indices": Ohara glass catalogue, technical
information 2.3 "Dispersion Formula"). The catalogues hold no other range, so the range of a catalogue glass is
the span of the wavelengths at which its catalogue row (opticalglass's copy of the maker's sheet) lists an index,
widened by 10 % at each end (:data:`EXTRAPOLATION_FRACTION`) and rounded outwards to 0.1 nm. The widening is what
the makers' own formula ranges allow beyond their tabulated lines: a dense flint such as N-SF11 lists no i-line
index, so its tabulated span is 404.6-2325.4 nm, while SCHOTT's Zemax catalogue (which opticalglass does not carry)
states 370-2500 nm for its formula, 8.6 % and 7.5 % beyond; without it a camera's 400 nm band would be refused
through such a glass. So N-BK7 is valid over 281.3-2558.0 nm and N-SF11 over 364.1-2558.0 nm. For the optiland
fallback it is the material file's own range (its tabulated data or its formula's stated range), widened the same
way (optiland's PMMA, measured over 436.8-1052 nm: 393.1-1157.2 nm). A wavelength
outside raises :class:`GlassError`. An obsolete Schott name (``SK16``, ``BK7``: still in OpticStudio's SCHOTT.AGF) is
its lead-free successor ``N-SK16``, ``N-BK7`` (made to the same n_d and V_d), with a warning.

Model glasses (a glass given by its index and Abbe number, as designs taken from patents give it: Zemax's
``GLAS ___BLANK 1 0 nd vd ...``, or ``material: "1.5168/64.17"`` in a YAML lens) use Buchdahl's quadratic dispersion
model in the chromatic coordinate omega = dl / (1 + 2.5 dl), dl in um from the d line (P. N. Robb & R. I. Mercado,
"Calculation of refractive indices using Buchdahl's chromatic coordinate", Applied Optics 22(8), 1983), evaluated
by opticalglass's ``Buchdahl``: its two coefficients satisfy n_F - n_C = (n_d - 1) / V_d and lie on opticalglass's
line ``v1 = b + m v2`` through the Schott catalogue (``Buchdahl2.b``, ``.m``). The coefficients are solved here:
opticalglass 1.1.1's ``Buchdahl2.update`` has the sign of the omega^2 term wrong (its N-BK7, 1.5168/64.17, has
V_d 68.0). Exact at the d line and for n_F - n_C; against the catalogue glass of the same n_d and V_d (N-BK7, N-SK16,
N-LAK9, N-BAF10, F2, N-SF6, N-SF11) within 2.2e-4 over 450-700 nm and 8e-4 at 400 nm, the partial dispersion of a
real glass not being in n_d and V_d (Zemax's dPgF is not used). Valid over the i to t lines (365-1014 nm), widened
as above.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

__all__ = ["GlassError", "CATALOGS", "refractive_index", "resolve_glass", "valid_range_nm", "model_glass_name",
           "parse_model_glass"]

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


#: the i and t lines (nm): the range of a model glass before widening (module docstring)
MODEL_GLASS_LINES_NM = (365.0, 1014.0)


def _model_glass(nd: float, vd: float, name: str):
    """opticalglass's ``Buchdahl`` of the model glass ``n_d``/``V_d`` (module docstring): with
    ``d1 = omega_F - omega_C`` and ``d2 = omega_F^2 - omega_C^2``, ``v1 d1 + v2 d2 = (n_d - 1) / V_d`` and
    ``v1 = b + m v2`` give ``v2 = ((n_d - 1) / V_d - b d1) / (m d1 + d2)``."""
    import numpy as np
    from opticalglass.buchdahl import Buchdahl, Buchdahl2, get_wv, omega

    wv0 = get_wv("d")
    om_f, om_c = omega(get_wv("F") - wv0), omega(get_wv("C") - wv0)
    d1, d2 = om_f - om_c, om_f ** 2 - om_c ** 2
    v2 = ((nd - 1.0) / vd - Buchdahl2.b * d1) / (Buchdahl2.m * d1 + d2)
    return Buchdahl(wv0, nd, np.array([Buchdahl2.b + Buchdahl2.m * v2, v2]), mat=name, cat="model glass")


def model_glass_name(nd: float, vd: float) -> str:
    """The material name of a model glass of index ``nd`` and Abbe number ``vd`` (:func:`parse_model_glass`)."""
    return f"{float(nd):.10g}/{float(vd):.10g}"


def parse_model_glass(name: str) -> tuple[float, float] | None:
    """``(n_d, V_d)`` of a model glass named ``"n_d/V_d"`` (e.g. ``"1.5168/64.17"``), None for any other name.

    Raises:
        GlassError: a name of that form whose values are not an optical glass's (1 < n_d < 3, 5 <= V_d <= 150).
    """
    parts = name.split("/")
    if len(parts) != 2:
        return None
    try:
        nd, vd = float(parts[0]), float(parts[1])
    except ValueError:
        return None
    if not (1.0 < nd < 3.0 and 5.0 <= vd <= 150.0):  # (finite too: NaN fails both)
        raise GlassError(f"glass {name!r}: a model glass n_d/V_d needs 1 < n_d < 3 and 5 <= V_d <= 150, got "
                         f"n_d {nd:g}, V_d {vd:g}")
    return nd, vd


@functools.lru_cache(maxsize=256)
def resolve_glass(name: str, catalogs: tuple[str, ...] = DEFAULT_CATALOGS):
    """The opticalglass glass object for ``name``, searched in ``catalogs`` (Zemax GCAT names) in order; a model
    glass ``"n_d/V_d"`` (module docstring) in none.

    Raises:
        GlassError: the name is in none of the catalogues (the message names the glass and the catalogues).
    """
    gf = _factory()
    model = parse_model_glass(name)
    if model is not None:
        return _model_glass(*model, name)
    tried, no_data = [], []
    for cat in catalogs:
        key = CATALOGS.get(cat.upper())
        if key is None:
            tried.append(f"{cat} (catalogue not available)")
            continue
        tried.append(cat)
        try:
            g = _catalogue_glass(gf, name, key)
        except ValueError as err:  # in the catalogue, without dispersion coefficients there
            no_data.append(f"{cat} ({err})")
            continue
        if g is not None:
            return g
    if no_data:
        raise GlassError(f"glass {name!r}: listed in {no_data} without dispersion coefficients (the catalogue data "
                         f"give no index for it); expected a glass with a dispersion formula, or a model glass "
                         f"'n_d/V_d'")
    others = [c for c in catalogs if c.upper() not in CATALOGS]
    hint = ""
    if others:
        g, maker = _optiland_material(name)
        if g is not None and (maker is None or maker.upper() in {c.upper() for c in catalogs}
                              or not _in_maker_catalogue(gf, name, maker)):
            # a maker's special material (ZERODUR, B270, IRG22, IG2, AMTIR-1: in OpticStudio's MISC / INFRARED,
            # not in the maker's optical-glass catalogue) is the MISC catalogue's to give
            return g
        tried.append("optiland database (for " + "/".join(others) + ")")
        if g is not None:  # a maker's glass the file did not declare (N-SF10 for GCAT OHARA MISC was Schott's)
            hint = f"; it is a {maker.upper()} glass: add {maker.upper()} to GCAT to use it"
    if any(c.upper() == "SCHOTT" for c in catalogs) and not name.upper().startswith("N-"):
        try:
            successor = gf.create_glass(f"N-{name}", "Schott")
        except Exception:
            successor = None
        if successor is not None:
            # an obsolete Schott glass (still in OpticStudio's SCHOTT.AGF: SK16 of Zemax's Cooke sample, BK7 of
            # older files) is its lead-free successor, made to the same n_d and V_d (SK16 1.62041 / 60.33, N-SK16
            # 1.62041 / 60.32): refusing it refused such files whole
            from ..._checks import warn_caller

            warn_caller(f"glass {name!r}: an obsolete Schott glass, not in the current catalogue data; using its "
                        f"successor N-{name} (made to the same n_d and V_d; indices differ by about 1e-4)")
            return successor
    raise GlassError(f"glass {name!r}: not found in the prescription's glass catalogues {tried}; expected a "
                     f"glass of one of them (add its catalogue to GCAT, or use a known glass name){hint}")


def _catalogue_glass(gf, name: str, key: str):
    """The glass ``name`` of opticalglass's catalogue ``key``, or None when it has none of that name. Names are
    matched without surrounding spaces and case (opticalglass keeps Hoya's ``'FDS20-W '`` with its trailing space:
    ``FDS20-W`` was not found). ValueError: the catalogue lists the glass without dispersion coefficients (Hikari's
    J-PSKH8: ``'-'`` cells), which had read as "not found in the catalogue" too."""
    try:
        return gf.create_glass(name, key)
    except ValueError:  # opticalglass reads the glass's coefficient cells as floats
        raise
    except Exception:  # opticalglass raises GlassNotFoundError (not exported uniformly across versions)
        pass
    try:
        cat = gf.get_glass_catalog(key)
    except Exception:  # pragma: no cover - every key of CATALOGS is an opticalglass catalogue
        return None
    want = name.strip().upper()
    for gn, gc in cat.glass_lookup.values():
        if str(gn).strip().upper() == want:
            return cat.create_glass(gn, gc)
    return None


class _OptilandGlass:
    """Adapter: an optiland material with opticalglass's ``rindex(wavelength_nm)``."""

    def __init__(self, material):
        self.material = material

    def rindex(self, wavelength_nm: float) -> float:
        import numpy as np

        return float(np.asarray(self.material.n(wavelength_nm / 1000.0)).ravel()[0])


def _in_maker_catalogue(gf, name: str, maker: str) -> bool:
    """Whether ``name`` is in ``maker``'s optical-glass catalogue (opticalglass), a catalogue the file did not
    declare: N-SF10 is Schott's, so GCAT OHARA MISC does not give it."""
    key = CATALOGS.get(maker.upper())
    if key is None:
        return False
    try:
        return _catalogue_glass(gf, name, key) is not None
    except ValueError:  # listed there without dispersion coefficients: that catalogue cannot give it
        return False


def _optiland_material(name: str):
    """``(glass, maker)``: the optiland material ``name`` (None when it has none) and, for a maker's catalogue glass
    of its database (``data-nk/glass/<maker>/``, not ``misc``), the maker's name, else None."""
    try:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from optiland.materials import Material

            material = Material(name)
    except Exception:  # not installed, or no such material
        return None, None
    path = Path(str(getattr(material, "filename", "")))
    maker = path.parts[path.parts.index("glass") + 1] if "glass" in path.parts[:-2] else None
    if maker in (None, "misc"):
        return _OptilandGlass(material), None
    # a maker's glass is that glass only under its own name (optiland reads BK7 as Schott's N-BK7 data)
    return (_OptilandGlass(material) if path.stem.upper() == name.upper() else None), maker


#: how far beyond its tabulated lines a catalogue glass's formula is used, as a fraction of the end wavelength (module
#: docstring)
EXTRAPOLATION_FRACTION = 0.10


def _catalogue_range_nm(glass) -> tuple[float, float] | None:
    """Span of the wavelengths (nm) at which an opticalglass catalogue row tabulates a refractive index."""
    from opticalglass.spectral_lines import get_wavelength

    waves = []
    for label, n in glass.glass_data()["refractive indices"].items():
        try:
            if not math.isfinite(float(n)):
                continue
            waves.append(float(get_wavelength(label)) if isinstance(label, str) else float(label))
        except (TypeError, ValueError, KeyError):  # blank cell, or a label that is not a wavelength
            continue
    waves = [w for w in waves if math.isfinite(w)]
    if not waves:
        return None
    return _widened(min(waves), max(waves))


def _widened(lo_nm: float, hi_nm: float) -> tuple[float, float]:
    """A data range widened by :data:`EXTRAPOLATION_FRACTION` at each end, rounded outwards to 0.1 nm."""
    lo, hi = lo_nm * (1 - EXTRAPOLATION_FRACTION), hi_nm * (1 + EXTRAPOLATION_FRACTION)
    return math.floor(lo * 10) / 10, math.ceil(hi * 10) / 10


@functools.lru_cache(maxsize=256)
def valid_range_nm(name: str, catalogs: tuple[str, ...] = DEFAULT_CATALOGS) -> tuple[float, float] | None:
    """The wavelength range (nm) over which the catalogue data of glass ``name`` are valid (module docstring), or
    None when the data state none (then no range is checked)."""
    g = resolve_glass(name, tuple(c.upper() for c in catalogs))
    if parse_model_glass(name) is not None:
        return _widened(*MODEL_GLASS_LINES_NM)
    if isinstance(g, _OptilandGlass):
        rng = getattr(g.material, "spectral_range", lambda _: None)("n")
        return None if rng is None else _widened(float(rng[0]) * 1000.0, float(rng[1]) * 1000.0)
    return _catalogue_range_nm(g)


def _source(g) -> str:
    if isinstance(g, _OptilandGlass):
        return "optiland material database"
    if getattr(g, "_catalog_name", None) == "model glass":  # (_model_glass)
        return "model glass n_d/V_d"
    try:
        return f"{g.catalog_name()} catalogue"
    except Exception:  # pragma: no cover - every opticalglass glass has one
        return "catalogue"


def refractive_index(name: str | None, wavelength_nm: float, catalogs: tuple[str, ...] = DEFAULT_CATALOGS) -> float:
    """Index of refraction (relative to air, as the catalogues give it) of ``name`` at ``wavelength_nm``.

    ``None``/``'AIR'`` is 1 (OpticStudio's convention: indices relative to air at the system temperature).
    ``catalogs`` is a sequence of Zemax GCAT names, e.g. ``("SCHOTT", "OHARA")``.

    Raises:
        GlassError: the glass is not in the catalogues, or ``wavelength_nm`` is outside its :func:`valid_range_nm`.
        ValueError: ``name`` is not a string, or ``catalogs`` is not a sequence of strings (a bare ``"SCHOTT"`` had
            been searched letter by letter, a list had failed in the cache as unhashable).
    """
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name: expected a glass name (str) or None for air, got {name!r}")
    if isinstance(catalogs, str) or not all(isinstance(c, str) for c in catalogs):
        raise ValueError(f"catalogs: expected a sequence of catalogue names such as ('SCHOTT', 'OHARA'), got "
                         f"{catalogs!r}")
    return _refractive_index(name, float(wavelength_nm), tuple(c.upper() for c in catalogs))


refractive_index.cache_clear = lambda: _refractive_index.cache_clear()  # as the memoised lookups have


@functools.lru_cache(maxsize=4096)
def _refractive_index(name: str | None, wavelength_nm: float, cats: tuple[str, ...]) -> float:
    """:func:`refractive_index` on checked arguments, memoised."""
    if name is None or name.upper() == "AIR":
        return 1.0
    g = resolve_glass(name, cats)
    rng = valid_range_nm(name, cats)
    wl = float(wavelength_nm)
    if rng is not None and not rng[0] <= wl <= rng[1]:
        raise GlassError(f"glass {name!r} ({_source(g)}): {wl:g} nm is outside its valid range {rng[0]:g}-{rng[1]:g} "
                         f"nm (the wavelengths its catalogue data cover); expected a wavelength in that range")
    n = float(g.rindex(wl))
    if not (n == n) or n < 1.0:
        raise GlassError(f"glass {name!r}: index {n} at {wavelength_nm} nm is outside the catalogue's "
                         f"valid range")
    return n
