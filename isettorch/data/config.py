"""Validated configuration for synthetic data: nested dicts of defaults, merged with a user's YAML.

An unknown key, or a value of the wrong type, raises ``ValueError`` naming the dotted key.
"""

from __future__ import annotations

import contextlib
import copy
import ctypes
import math
import sys
import threading
from pathlib import Path
from typing import Any

import torch
import yaml

from .._checks import SEED_LIMIT, check_integer, check_seed, is_integer, seed_for  # noqa: F401 (re-exported)

__all__ = ["SCENE_DEFAULTS", "CAMERA_DEFAULTS", "SYNTH_DEFAULTS", "NATURAL_DEFAULTS", "COMPONENTS",
           "DEFAULT_COMPONENTS", "WAVELENGTH_RANGE_NM", "TARGETS", "check_targets", "merge_config", "pair_config",
           "check_integer", "check_seed", "natural_config", "load_config", "seed_for", "one_thread", "tune_allocator"]

SCENE_DEFAULTS: dict[str, Any] = {
    # which scene generator: "layouts" (isettorch.data.scenes.generate_scene, the keys below) or "natural"
    # (isettorch.data.natural.generate_natural with the options in "natural": NATURAL_DEFAULTS keys but size)
    "generator": "layouts",
    "natural": {},
    "height": 128,
    "width": 128,
    "wavelengths_nm": [400.0, 700.0, 10.0],  # start, stop, step (inclusive)
    "palette_size": 8,
    "layouts": {"dead_leaves": 0.4, "gradients": 0.1, "edges": 0.15, "lines": 0.15, "textures": 0.2},
    "reflectance_model": "mixed",  # pca | sigmoid | mixed
    "pca_fraction": 0.5,
    "illuminants": {"daylight": 0.4, "blackbody": 0.2, "fluorescent": 0.2, "led": 0.2},
    "cct_range_k": {"daylight": [4000.0, 25000.0], "blackbody": [2000.0, 10000.0], "led": [2700.0, 6500.0]},
    "two_light_probability": 0.25,  # a second light across the image (smooth transition)
    "shadow_probability": 0.25,  # a cast shadow lit only by skylight, in a scene with one light (0.19 of all)
    "shadow_ambient": [0.02, 0.3],  # skylight luminance relative to the direct light
    "second_light_ratio": [0.3, 3.0],  # luminance of light 2 / light 1
    "hdr_decades": [0.0, 3.0],  # illumination range across the image, log10(max / min)
    "mean_luminance_cd_m2": [1.0, 5000.0],  # log-uniform
    # drawn by generate_scene / SyntheticSceneDataset; camera pairs take the FOV from the sensor (one scene sample
    # per pixel), so for them another value is an error (pair_config)
    "hfov_deg": [4.0, 20.0],
    "distance_m": 1.2,
}

#: the scene keys only the layouts generator reads (the natural one takes its options from ``natural``)
LAYOUTS_ONLY_KEYS = ("palette_size", "layouts", "reflectance_model", "pca_fraction", "illuminants", "cct_range_k",
                     "two_light_probability", "shadow_probability", "shadow_ambient", "second_light_ratio",
                     "hdr_decades")

CAMERA_DEFAULTS: dict[str, Any] = {
    "f_number": [2.0, 2.8, 4.0, 5.6, 8.0],  # discrete stops: OTFs are cached per (stop, pixel size)
    "focal_length_m": 4e-3,
    "pixel_size_m": [1.4e-6, 2.0e-6, 2.8e-6],
    "fill_factor": 0.9,
    "full_well_e": [6000.0, 20000.0],
    "read_noise_e": [1.0, 6.0],
    "dark_current_e_per_s": [0.5, 20.0],
    "dsnu_sigma_e": [0.0, 2.0],
    "prnu_sigma_percent": [0.0, 1.5],
    "analog_gain": [1.0, 16.0],  # log-uniform; ISO = 100 x gain
    "bits": 12,
    "black_level_dn": 64.0,
    "exposure_ev": [-2.0, 1.0],  # x 2^EV on auto exposure (98th percentile at 80 % of white, at most 10 s): <= 20 s
    "peak_qe": [0.35, 0.6],
    "cfa_patterns": ["RGGB"],  # any of RGGB, GRBG, GBRG, BGGR; one drawn per sample
    "qe_variation": 0.0,  # 0 = the nominal curves; > 0 shifts each channel by up to this many x 10 nm
    "margin_px": 8,  # scene border beyond the sensor (blur support; the optics' buffer reaches twice as far, at
    # least 16 samples, the scene's edge continued); 128 + 2 x 8 = 144 is an FFT-friendly size
    # optics: {} = diffraction-limited at the drawn f_number / focal_length_m; else a mapping for
    # isettorch.optics.factory.build_optics (e.g. {type: lens, lens: cooke_triplet}), whose own f-number and focal
    # length then replace the drawn ones (f_number / focal_length_m lists are still drawn, so other draws keep
    # their order)
    "optics": {},
}

# The natural scene generator's options (isettorch.data.natural, where each component is described); here, with
# their validation, so that config (which checks scene.natural) and the generator share them without an import
# circle.
NATURAL_DEFAULTS: dict = {
    "size": 128,
    "wavelengths_nm": [400.0, 700.0, 10.0],
    "mean_radiance_scale": 1.0,  # the illuminant is scaled to luminance 1 cd/m^2 from a white; x this
    "components": {
        "palette": {"enabled": True, "materials": [2, 8], "measured": 0.35, "recovery": 0.35, "random": 0.3,
                    "grey_probability": 0.15, "dye": {"probability": 0.0, "concentration": [1.0, 4.0]}},
        "illuminant": {"enabled": True, "kinds": {"daylight": 0.4, "blackbody": 0.25, "led": 0.2,
                                                  "fluorescent": 0.15},
                       "mixed_probability": 0.2},
        "dead_leaves": {"enabled": True, "leaves": [500, 1200], "exponent": 3.0, "r_min_px": 0.8,
                        "r_max_fraction": 0.5, "brightness": [0.1, 1.0]},
        "textured_leaves": {"enabled": True, "probability": 0.5, "noise_exponent": [0.8, 1.6],
                            "grating_cpp": [0.02, 0.3], "kinds": {"noise": 0.4, "grating": 0.25, "colour_line": 0.35},
                            "min_size_px": 10},
        "colour_correlation": {"enabled": True, "exponent": [0.7, 1.2], "contrast": [0.05, 0.35],
                               "chromatic_radius_px": 8.0, "chromatic_detail_probability": 0.5},
        "depth_layers": {"enabled": True, "probability": 0.4, "foreground_leaves": [3, 12],
                         "defocus_diopters": [0.0, 0.5, 1.0, 2.0], "f_number": 2.0, "focal_length_m": 0.004,
                         "pixel_size_m": 1.4e-6},
        "fine_detail": {"enabled": True, "probability": 0.4, "items": [1, 4], "grating_cpp": [0.15, 0.7],
                        "line_width_px": [0.3, 2.0], "supersample": 4},
        "grain": {"enabled": True, "probability": 0.5, "amplitude": [0.002, 0.015], "exponent": [0.0, 0.6],
                  "contrast": 0.7, "dye_edges_nm": [490.0, 580.0], "dye_width_nm": 12.0,
                  "relative": {"probability": 0.0, "contrast": [0.01, 0.08]}},
        "specular": {"enabled": True, "probability": 0.0, "amplitude": [0.02, 0.3], "glossy_fraction": 0.5,
                     "exponent": [0.3, 1.2], "contrast": [0.3, 1.0]},
    },
}
COMPONENTS = tuple(NATURAL_DEFAULTS["components"])
#: the components that draw in the default (version-5) scenes; ``specular`` is drawn only with a probability > 0
DEFAULT_COMPONENTS = tuple(c for c in COMPONENTS if NATURAL_DEFAULTS["components"][c].get("probability", 1) > 0)


def natural_config(config: dict | None = None, **overrides) -> dict:
    """``NATURAL_DEFAULTS`` updated with ``config`` (nested dicts merged); unknown keys raise naming the key.
    ``overrides``: ``disable=("fine_detail", ...)`` switches components off."""
    out = copy.deepcopy(NATURAL_DEFAULTS)

    def merge(dst, src, path):
        for k, v in src.items():
            if k not in dst:
                raise ValueError(f"config: unknown key {path + k!r}; expected one of {sorted(dst)}")
            if isinstance(dst[k], dict) and k != "kinds":
                if not isinstance(v, dict):
                    raise ValueError(f"config: {path + k!r} expected a mapping, got {v!r}")
                merge(dst[k], v, path + k + ".")
            else:
                dst[k] = v

    merge(out, config or {}, "")
    for name in overrides.pop("disable", ()):
        if name not in COMPONENTS:
            raise ValueError(f"disable: expected component names from {COMPONENTS}, got {name!r}")
        out["components"][name]["enabled"] = False
    if overrides:
        raise ValueError(f"natural_config: unknown arguments {sorted(overrides)}")
    _check_natural_values(out, NATURAL_DEFAULTS, "")
    _check_wavelengths(out["wavelengths_nm"], "config: 'wavelengths_nm'")
    size = out["size"]
    if isinstance(size, bool) or not isinstance(size, int) or size < 16:
        raise ValueError(f"config: 'size' expected an integer >= 16 pixels, got {size!r}")
    comp = out["components"]
    # what the per-item generator refuses at draw time (without the key's name) and the batched one drew anyway (an
    # audit of 2026-12-01): a zero total of palette kinds (the stream drew 'recovery' only), a grating beyond
    # Nyquist, leaves whose largest radius is below the smallest (the stream drew radii under r_min_px)
    pal = comp["palette"]
    if pal["enabled"] and pal["measured"] + pal["recovery"] + pal["random"] <= 0:
        raise ValueError("config: 'components.palette' expected a positive total of the kind weights measured, "
                         f"recovery, random, got {pal['measured']}, {pal['recovery']}, {pal['random']}")
    if comp["textured_leaves"]["grating_cpp"][1] > 0.5:  # sampled at pixel centres: aliased above (1 and 2: flat)
        raise ValueError(f"config: 'components.textured_leaves.grating_cpp' expected frequencies in (0, 0.5] cycles "
                         f"per pixel (the Nyquist frequency), got {comp['textured_leaves']['grating_cpp']!r}")
    dl = comp["dead_leaves"]
    if not dl["r_max_fraction"] * size > dl["r_min_px"]:
        raise ValueError(f"config: 'components.dead_leaves.r_max_fraction' x size ({dl['r_max_fraction']} x {size} "
                         f"px) expected above r_min_px ({dl['r_min_px']} px): the leaves' largest radius below their "
                         f"smallest")
    _check_optional(out["components"]["palette"]["dye"], "palette.dye", "concentration")
    _check_optional(out["components"]["grain"]["relative"], "grain.relative", "contrast")
    _check_optional(out["components"]["specular"], "specular", "amplitude")
    sp = out["components"]["specular"]
    if not isinstance(sp["glossy_fraction"], (int, float)) or not 0 < sp["glossy_fraction"] <= 1:
        raise ValueError(f"config: 'components.specular.glossy_fraction' expected a fraction in (0, 1], "
                         f"got {sp['glossy_fraction']!r}")
    for key, lo_ok, hi_ok in (("exponent", 0.0, 4.0), ("contrast", 0.0, 3.0)):
        r = sp[key]
        if (not isinstance(r, (list, tuple)) or len(r) != 2 or not all(isinstance(c, (int, float)) for c in r)
                or not lo_ok <= r[0] <= r[1] <= hi_ok):
            raise ValueError(f"config: 'components.specular.{key}' expected a range [lo, hi] with "
                             f"{lo_ok} <= lo <= hi <= {hi_ok}, got {r!r}")
    return out


# The natural config's numbers are sizes, rates, amplitudes and exponents: none is negative. These must also be
# above 0 (a zero divided: r_min_px and brightness gave ZeroDivisionError at batch time, supersample 0 a stride
# error) or at least a minimum; (bound, open).
_NATURAL_LOWER = {"mean_radiance_scale": (0.0, True), "components.palette.materials": (1, False),
                  "components.dead_leaves.r_min_px": (0.0, True), "components.dead_leaves.brightness": (0.0, True),
                  "components.textured_leaves.grating_cpp": (0.0, True),
                  "components.depth_layers.f_number": (0.5, False),
                  "components.depth_layers.focal_length_m": (0.0, True),
                  "components.depth_layers.pixel_size_m": (0.0, True),
                  "components.fine_detail.grating_cpp": (0.0, True),
                  "components.fine_detail.line_width_px": (0.0, True),
                  "components.fine_detail.supersample": (1, False), "components.grain.dye_width_nm": (0.0, True),
                  "components.grain.amplitude": (0.0, True)}


def _same_value(v, ref) -> bool:
    """``v`` is ``ref`` in value and type, throughout (``==`` alone holds for True, 1 and 1.0, and for dicts and lists
    of them: ``enabled: 1``, ``probability: false`` and ``materials: [2.0, 8.0]`` had passed as defaults; NaN never
    equals itself)."""
    if type(v) is not type(ref):
        return False
    if isinstance(ref, dict):
        return v.keys() == ref.keys() and all(_same_value(v[k], ref[k]) for k in ref)
    if isinstance(ref, (list, tuple)):
        return len(v) == len(ref) and all(_same_value(a, b) for a, b in zip(v, ref))
    return v == ref


def _check_natural_values(cfg: dict, defaults: dict, path: str) -> None:
    """Each value of a merged natural config of the kind of its default: a bool, a finite number (an integer where the
    default is one), a range ``[lo, hi]`` (two such numbers, lo <= hi) where the default is one, a non-empty list of
    finite numbers where the default lists choices, weights for ``kinds``; ``*probability`` keys in [0, 1], the
    fractions in (0, 1]; every number >= 0, or above the bound of :data:`_NATURAL_LOWER`; the dead leaves' size
    exponent not 1 (their radii's inverse CDF divides by 1 - exponent)."""
    for key, ref in defaults.items():
        v = cfg[key]
        if _same_value(v, ref):  # the default (valid): most of a config, skipped at once
            continue
        where = f"config: {path + key!r}"
        lo, lo_open = _NATURAL_LOWER.get(path + key, (0.0, False))
        if key == "kinds":
            _check_weights(v, where)
            unknown = sorted(set(v) - set(ref))  # (PairStream drew the last kind for 'candle', dropped 'blackbdy')
            if unknown:
                raise ValueError(f"{where}: {unknown[0]!r}: unknown kind; expected some of {sorted(ref)}")
        elif isinstance(ref, dict):
            _check_natural_values(v, ref, path + key + ".")
        elif isinstance(ref, bool):
            if not isinstance(v, bool):
                raise ValueError(f"{where}: expected true or false, got {v!r}")
        elif _is_number(ref):
            integer = isinstance(ref, int)
            if key.endswith("probability"):
                _check_number(v, where, 0.0, 1.0, what="a probability")
            elif key.endswith("fraction"):
                _check_number(v, where, 0.0, 1.0, lo_open=True, what="a fraction")
            else:
                _check_number(v, where, lo, lo_open=lo_open, integer=integer,
                              what="an integer" if integer else "a number")
                if path + key == "components.dead_leaves.exponent" and v == 1:
                    raise ValueError(f"{where}: expected an exponent other than 1 (the leaf radii's inverse CDF "
                                     f"divides by 1 - exponent), got {v!r}")
        elif isinstance(ref, list) and len(ref) == 2:
            integer = all(isinstance(x, int) for x in ref)
            kind = is_integer if integer else _is_number
            if (not isinstance(v, (list, tuple)) or len(v) != 2 or not all(kind(x) and math.isfinite(x) for x in v)
                    or not v[0] <= v[1] or not _in(v[0], lo, math.inf, lo_open, False)):
                what = "integers" if integer else "finite numbers"
                raise ValueError(f"{where}: expected a range [lo, hi] of two {what} with "
                                 f"{lo:g} {'<' if lo_open else '<='} lo <= hi, got {v!r}")
        elif isinstance(ref, list):
            if (not isinstance(v, (list, tuple)) or not v
                    or not all(_is_number(x) and math.isfinite(x) and _in(x, lo, math.inf, lo_open, False) for x in v)):
                raise ValueError(f"{where}: expected a non-empty list of finite numbers "
                                 f"{'>' if lo_open else '>='} {lo:g}, got {v!r}")


def _check_optional(block: dict, name: str, key: str) -> None:
    """An optional draw's settings: ``probability`` in [0, 1] and a range ``key`` = [lo, hi] with 0 < lo <= hi."""
    prob, rng = block["probability"], block[key]
    if (not isinstance(prob, (int, float)) or not 0 <= prob <= 1 or not isinstance(rng, (list, tuple))
            or len(rng) != 2 or not all(isinstance(c, (int, float)) for c in rng) or not 0 < rng[0] <= rng[1]):
        raise ValueError(f"config: 'components.{name}' expected a probability in [0, 1] and a {key} range [lo, hi] "
                         f"with 0 < lo <= hi, got {block}")


#: the targets a camera pair can hold besides ``raw`` and ``meta`` (:mod:`isettorch.data.camera_pairs`)
TARGETS = ("noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb")


def check_targets(targets) -> tuple[str, ...]:
    """``targets`` (names from :data:`TARGETS`, any order) in canonical order; ValueError naming a bad one."""
    if isinstance(targets, str):
        targets = (targets,)
    try:
        names = tuple(targets)
    except TypeError:
        raise ValueError(f"targets: expected a target name or a sequence of names from {TARGETS}, got "
                         f"{targets!r}") from None
    bad = [t for t in names if t not in TARGETS]
    if bad:
        raise ValueError(f"targets: expected names from {TARGETS}, got {bad[0]!r}")
    return tuple(t for t in TARGETS if t in names)


SYNTH_DEFAULTS: dict[str, Any] = {
    "seed": 0,
    "shard_size": 64,
    "dtype": "float32",
    # targets written besides raw and meta (camera_pairs.TARGETS; fewer = smaller shards and faster generation)
    "targets": ["noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb"],
    "scene": SCENE_DEFAULTS,
    "camera": CAMERA_DEFAULTS,
}


def _merge(defaults: dict, user: dict, path: str) -> dict:
    if not isinstance(user, dict):
        raise ValueError(f"{path or 'config'}: expected a mapping, got {type(user).__name__}")
    out = copy.deepcopy(defaults)
    for key, value in user.items():
        where = f"{path}.{key}" if path else str(key)
        if key not in defaults:
            raise ValueError(f"{where}: unknown config key; expected one of {sorted(defaults)}")
        ref = defaults[key]
        if key in ("natural", "optics") and isinstance(ref, dict) and not ref:  # free mappings, checked below
            if not isinstance(value, dict):
                raise ValueError(f"{where}: expected a mapping, got {value!r}")
            out[key] = copy.deepcopy(value)
        elif isinstance(ref, dict) and key not in ("layouts", "illuminants", "cct_range_k"):
            out[key] = _merge(ref, value, where)
        elif isinstance(ref, dict):
            if not isinstance(value, dict):
                raise ValueError(f"{where}: expected a mapping, got {value!r}")
            allowed = set(ref)
            bad = [k for k in value if k not in allowed]
            if bad:
                raise ValueError(f"{where}.{bad[0]}: unknown key; expected one of {sorted(allowed)}")
            out[key] = dict(value) if key != "cct_range_k" else {**ref, **value}
        elif isinstance(ref, bool) or isinstance(value, bool):
            if type(ref) is not type(value):
                raise ValueError(f"{where}: expected {type(ref).__name__}, got {value!r}")
            out[key] = value
        elif isinstance(ref, (int, float)):
            if isinstance(value, (list, tuple)) and key in _NUMBER_OR_RANGE:
                out[key] = _like(list(value), ref)
            elif not isinstance(value, (int, float)):
                raise ValueError(f"{where}: expected a number, got {value!r}")
            elif isinstance(ref, int):  # an integer key: an integral float (YAML 12.0) is that integer, 12.5 is not
                if not (isinstance(value, int) or (math.isfinite(value) and float(value).is_integer())):
                    raise ValueError(f"{where}: expected an integer, got {value!r}")
                out[key] = int(value)
            else:
                out[key] = float(value)
        elif isinstance(ref, list):
            if isinstance(value, (int, float)) and len(ref) == 2:
                out[key] = _like([value, value], ref[0])
            elif not isinstance(value, (list, tuple)):
                raise ValueError(f"{where}: expected a list, got {value!r}")
            else:
                out[key] = _like(list(value), ref[0] if ref else None)
        elif isinstance(ref, str):
            if not isinstance(value, str):
                raise ValueError(f"{where}: expected a string, got {value!r}")
            out[key] = value
        else:  # pragma: no cover
            out[key] = value
    return out


def _like(values: list, ref) -> list:
    """``values`` with whole numbers as floats where the default ``ref`` is a float: ``black_level_dn: 64`` and the
    default 64.0 are one config, and hash as one (``writer.config_hash``; an int hashed apart, so a resumed or
    second-rank write of the same items was refused as another config)."""
    if not isinstance(ref, float):
        return values
    return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in values]


#: number keys that also take a range ``[lo, hi]`` (drawn per item); other number keys take one number
_NUMBER_OR_RANGE = ("distance_m",)
#: the wavelengths the scene generators' spectral data cover: their reflectance models are fitted on measured
#: reflectances sampled 400:5:700 nm (:func:`isettorch.data.spectra._measured_reflectances`); outside, the PCA
#: model's basis is 0 and its draws are NaN
WAVELENGTH_RANGE_NM = (400.0, 700.0)
#: the CCTs each illuminant kind can draw (K): CIE daylight's polynomials hold on 4000-25000 K (CIE 015:2018);
#: the on-locus LED phosphor table spans 40-1000 mired; a blackbody from 100 K (colder, it has no visible spectrum
#: left to normalise: at 1 K the light's luminance was 0 / 0)
_CCT_BOUNDS_K = {"daylight": (4000.0, 25000.0), "blackbody": (100.0, math.inf), "led": (1000.0, 25000.0)}


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _bounds_text(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    """`` in [lo, hi]``, `` > lo``... (empty for no bounds)."""
    if lo == -math.inf and hi == math.inf:
        return ""
    if hi == math.inf:
        return f" {'>' if lo_open else '>='} {lo:g}"
    if lo == -math.inf:
        return f" {'<' if hi_open else '<='} {hi:g}"
    return f" in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def _in(x: float, lo: float, hi: float, lo_open: bool, hi_open: bool) -> bool:
    return (lo < x if lo_open else lo <= x) and (x < hi if hi_open else x <= hi)


def _check_number(value, where: str, lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False,
                  hi_open: bool = False, integer: bool = False, what: str = "a number") -> None:
    """A finite number (an integer with ``integer``) in the interval ``lo .. hi``; else ValueError naming ``where``."""
    ok = (is_integer(value) if integer else _is_number(value)) and math.isfinite(value) and \
        _in(value, lo, hi, lo_open, hi_open)
    if not ok:
        raise ValueError(f"{where}: expected {what}{_bounds_text(lo, hi, lo_open, hi_open)}, got {value!r}")


# What a scene may ask for: from far below starlight (1e-4 cd/m2) to far above the sun's disk (1.6e9 cd/m2), and
# up to 12 decades of illumination across an image (sunlit snow to a moonless night's shadow is about 10). Within
# these the float32 radiance, irradiance and electron rates stay finite (float32 overflowed from 1e22 cd/m2 with an
# error naming the sensor's electron rate, not this key).
MEAN_LUMINANCE_BOUNDS_CD_M2 = (1e-20, 1e12)
MAX_HDR_DECADES = 12.0


def _check_range(cfg: dict, key: str, path: str, lo: float = -math.inf, hi: float = math.inf, *,
                 lo_open: bool = False, hi_open: bool = False, log: bool = False, scalar: bool = True) -> None:
    """``cfg[key]``: a range ``[lo, hi]`` drawn per item (two finite numbers, lo <= hi, both in the interval
    ``lo .. hi`` of the key) or, with ``scalar``, one such number (a constant). ``log``: drawn log-uniformly, so a
    range needs lo > 0 (a constant may be 0 where the key allows it): the draws would otherwise fall back to
    uniform ones."""
    v, where = cfg[key], f"{path}.{key}"
    bounds = _bounds_text(lo, hi, lo_open, hi_open)
    bounds = f", both{bounds}" if bounds else ""
    if scalar and _is_number(v):
        _check_number(v, where, lo, hi, lo_open=lo_open, hi_open=hi_open)
        return
    if (not isinstance(v, (list, tuple)) or len(v) != 2 or not all(_is_number(x) and math.isfinite(x) for x in v)
            or not v[0] <= v[1] or not all(_in(x, lo, hi, lo_open, hi_open) for x in v)):
        raise ValueError(f"{where}: expected a range [lo, hi] of two finite numbers with lo <= hi{bounds}, got {v!r}")
    if log and not v[0] > 0 and v[0] != v[1]:
        raise ValueError(f"{where}: drawn log-uniformly, so a range [lo, hi] needs lo > 0 (or lo == hi, a "
                         f"constant), got {v!r}")


def _check_choices(cfg: dict, key: str, path: str, lo: float = 0.0, lo_open: bool = True, why: str = "") -> None:
    """``cfg[key]``: a non-empty list of finite numbers > ``lo`` (>= with ``lo_open=False``), one drawn per item."""
    v = cfg[key]
    if (not isinstance(v, (list, tuple)) or not v
            or not all(_is_number(x) and math.isfinite(x) and _in(x, lo, math.inf, lo_open, False) for x in v)):
        raise ValueError(f"{path}.{key}: expected a non-empty list of finite numbers {'>' if lo_open else '>='} "
                         f"{lo:g} (one drawn per item{why}), got {v!r}")


def _check_weights(ws, where: str) -> None:
    if (not isinstance(ws, dict) or not ws
            or any(not _is_number(x) or not math.isfinite(x) or x < 0 for x in ws.values()) or sum(ws.values()) <= 0):
        raise ValueError(f"{where}: expected non-negative weights with a positive sum, got {ws!r}")


def _check_wavelengths(wl, where: str) -> None:
    """A scene grid ``[start, stop, step]`` (inclusive) inside :data:`WAVELENGTH_RANGE_NM`, whole steps."""
    lo_nm, hi_nm = WAVELENGTH_RANGE_NM
    if (not isinstance(wl, (list, tuple)) or len(wl) != 3 or not all(_is_number(x) and math.isfinite(x) for x in wl)
            or not wl[2] > 0 or not lo_nm <= wl[0] <= wl[1] <= hi_nm):
        raise ValueError(f"{where}: expected [start, stop, step] with {lo_nm:g} <= start <= stop <= {hi_nm:g} nm "
                         f"(the measured reflectances the scene spectra are modelled on cover {lo_nm:g}-{hi_nm:g} nm) "
                         f"and step > 0, got {wl!r}")
    steps = (wl[1] - wl[0]) / wl[2]
    if abs(steps - round(steps)) > 1e-6:  # the grid would stop short of `stop`
        raise ValueError(f"{where}: expected stop - start to be a whole number of steps (the grid start:step:stop "
                         f"includes stop), got {wl!r}")


def _check_scene(scene: dict, sp: str, camera: dict | None = None) -> None:
    """Validate a merged scene config; ``camera`` (a merged camera config): for camera pairs, whose scene field of
    view follows the sensor and whose sizes are whole Bayer cells."""
    if scene["generator"] not in ("layouts", "natural"):
        raise ValueError(f"{sp}.generator: expected 'layouts' or 'natural', got {scene['generator']!r}")
    for key in ("height", "width"):
        _check_number(scene[key], f"{sp}.{key}", 2, integer=True, what="an integer number of pixels")
    h, w = scene["height"], scene["width"]
    if camera is not None and (h % 2 or w % 2):
        raise ValueError(f"{sp}.height/width: expected even sizes (whole Bayer cells), got {h}x{w}")
    margin = camera["margin_px"] if camera is not None else 0
    if scene["generator"] == "layouts" and max(h, w) + 2 * margin < 5:  # dead leaves: radii 2.5 px to 0.6 x size
        raise ValueError(f"{sp}.height/width: the layouts generator needs a scene of at least 5 pixels on its longer "
                         f"side (sensor + 2 x margin), got {h + 2 * margin}x{w + 2 * margin}")
    _check_wavelengths(scene["wavelengths_nm"], f"{sp}.wavelengths_nm")
    _check_number(scene["palette_size"], f"{sp}.palette_size", 1, integer=True, what="an integer number of colours")
    for key in ("layouts", "illuminants"):
        _check_weights(scene[key], f"{sp}.{key}")
    if scene["reflectance_model"] not in ("pca", "sigmoid", "mixed"):
        raise ValueError(f"{sp}.reflectance_model: expected pca, sigmoid or mixed, got "
                         f"{scene['reflectance_model']!r}")
    for key in ("pca_fraction", "two_light_probability", "shadow_probability"):
        _check_number(scene[key], f"{sp}.{key}", 0.0, 1.0, what="a probability")
    for kind in scene["cct_range_k"]:
        lo, hi = _CCT_BOUNDS_K[kind]
        _check_range(scene["cct_range_k"], kind, f"{sp}.cct_range_k", lo, hi, lo_open=lo == 0, scalar=False)
    _check_range(scene, "shadow_ambient", sp, 0.0, log=True, scalar=False)
    _check_range(scene, "second_light_ratio", sp, 0.0, log=True, scalar=False)
    _check_range(scene, "hdr_decades", sp, 0.0, MAX_HDR_DECADES, scalar=False)
    _check_range(scene, "mean_luminance_cd_m2", sp, *MEAN_LUMINANCE_BOUNDS_CD_M2, log=True, scalar=False)
    if camera is None:
        _check_range(scene, "hfov_deg", sp, 0.0, 180.0, lo_open=True, hi_open=True, scalar=False)
    elif scene["hfov_deg"] != SCENE_DEFAULTS["hfov_deg"]:
        # the camera pairs put one scene sample on one pixel: hfov = 2 atan(pitch x width / (2 x image distance))
        raise ValueError(f"{sp}.hfov_deg: camera pairs take the scene's field of view from the sensor (pixel pitch x "
                         f"width at the image distance), so this key has no effect on them; remove it (got "
                         f"{scene['hfov_deg']!r})")
    _check_range(scene, "distance_m", sp, 0.0, lo_open=True)
    if camera is not None and not camera["optics"]:  # a thin lens images only objects beyond its focal length (a
        # range reaching below it failed at the first such draw, after 53 shards, and again on every rerun)
        near = scene["distance_m"] if _is_number(scene["distance_m"]) else scene["distance_m"][0]
        if not near > camera["focal_length_m"]:
            cp = sp[:-len("scene")] + "camera" if sp.endswith("scene") else "camera"
            raise ValueError(f"{sp}.distance_m: expected object distances beyond {cp}.focal_length_m "
                             f"({camera['focal_length_m']:g} m), got {scene['distance_m']!r}")
    for key in ("size", "wavelengths_nm", "mean_radiance_scale"):
        if key in scene["natural"]:  # set by the scene: the generator's own value would be ignored
            follows = {"size": f"{sp}.height/width and the camera margin", "wavelengths_nm": f"{sp}.wavelengths_nm",
                       "mean_radiance_scale": f"{sp}.mean_luminance_cd_m2"}[key]
            raise ValueError(f"{sp}.natural.{key}: the natural scene's {key} follows {follows}; remove it "
                             f"(got {scene['natural'][key]!r})")
    if scene["natural"]:
        try:  # at the size the scene is generated at (square, at least 16: camera_pairs._natural_scene)
            natural_config(dict(scene["natural"], size=max(16, h + 2 * margin, w + 2 * margin)))
        except ValueError as err:
            raise ValueError(f"{sp}.natural: {err}") from err
    # a key the chosen generator does not read is an error, as hfov_deg is above (accepted, it changed nothing)
    if scene["generator"] == "natural":
        unread = [key for key in LAYOUTS_ONLY_KEYS if scene[key] != SCENE_DEFAULTS[key]]
        if unread:
            raise ValueError(f"{sp}.{unread[0]}: the natural generator does not read it (its options are "
                             f"{sp}.natural: NATURAL_DEFAULTS keys), so it has no effect; remove it "
                             f"(set: {unread})")
    elif scene["natural"]:
        raise ValueError(f"{sp}.natural: options of the natural generator, which {sp}.generator 'layouts' does not "
                         f"read; set {sp}.generator: natural, or remove them (got {scene['natural']!r})")


def _check_camera(cam: dict, cp: str) -> None:
    """Validate a merged camera config (the camera pairs' drawn cameras)."""
    bad = [p for p in cam["cfa_patterns"] if p not in ("RGGB", "GRBG", "GBRG", "BGGR")]
    if bad or not cam["cfa_patterns"]:
        raise ValueError(f"{cp}.cfa_patterns: expected Bayer patterns from RGGB, GRBG, GBRG, BGGR, got "
                         f"{cam['cfa_patterns']!r}")
    _check_choices(cam, "f_number", cp, 0.5, lo_open=False, why="; 0.5: the fastest lens in air, N = 1 / (2 NA)")
    _check_choices(cam, "pixel_size_m", cp)
    _check_number(cam["focal_length_m"], f"{cp}.focal_length_m", 0.0, lo_open=True)
    _check_number(cam["fill_factor"], f"{cp}.fill_factor", 0.0, 1.0, lo_open=True, what="a fraction")
    _check_range(cam, "full_well_e", cp, 0.0, lo_open=True, log=True)
    _check_range(cam, "read_noise_e", cp, 0.0)
    _check_range(cam, "dark_current_e_per_s", cp, 0.0, log=True)
    _check_range(cam, "dsnu_sigma_e", cp, 0.0)
    _check_range(cam, "prnu_sigma_percent", cp, 0.0, 20.0)  # the sensor's MAX_PRNU_SIGMA_PERCENT
    _check_range(cam, "analog_gain", cp, 0.0, lo_open=True, log=True)
    _check_range(cam, "exposure_ev", cp)
    _check_range(cam, "peak_qe", cp, 0.0, 1.0, lo_open=True)
    _check_number(cam["bits"], f"{cp}.bits", 1, 32, integer=True, what="an integer number of ADC bits")
    _check_number(cam["black_level_dn"], f"{cp}.black_level_dn", 0.0, 2 ** cam["bits"] - 1, hi_open=True,
                  what=f"a black level in DN ({cp}.bits = {cam['bits']}: below 2^{cam['bits']} - 1)")
    # at most +-100 nm: at 100 (+-1000 nm) a channel left the grid, its QE was 0 and the white metadata NaN
    _check_number(cam["qe_variation"], f"{cp}.qe_variation", 0.0, 10.0,
                  what="a shift scale (x 10 nm per channel)")
    _check_number(cam["margin_px"], f"{cp}.margin_px", 0, integer=True, what="an integer number of pixels")
    if cam["optics"]:  # checked by building it (then dropped): the factory's own checks of type, keys, files
        from ..optics.factory import build_optics

        # the configured optics' own f-number and focal length are used (the drawn ones only keep the draws): a
        # value given beside it had no effect, though the manifest recorded it
        unread = [key for key in ("f_number", "focal_length_m") if cam[key] != CAMERA_DEFAULTS[key]]
        if unread:
            raise ValueError(f"{cp}.{unread[0]}: {cp}.optics is set, whose own f-number and focal length are used, so "
                             f"{cp}.{unread[0]} has no effect; set it in {cp}.optics, or remove it")

        try:
            build_optics(cam["optics"])
        except (TypeError, ValueError, OSError) as err:
            kind = cam["optics"].get("type", "diffraction_limited")
            raise ValueError(f"{cp}.optics[type={kind!r}]: {err}") from err


def merge_config(user: dict | None, defaults: dict = SYNTH_DEFAULTS, path: str = "") -> dict:
    """Defaults overridden by ``user``; validates keys, types and ranges (a bad value raises ``ValueError`` naming
    its dotted key). ``defaults``: :data:`SYNTH_DEFAULTS` (a whole ``isettorch synth`` config: camera pairs),
    :data:`SCENE_DEFAULTS` or :data:`CAMERA_DEFAULTS` (one section; ``path`` its name). Camera pairs
    (:class:`~isettorch.data.camera_pairs.CameraPairDataset`, :class:`~isettorch.data.PairStream`) validate their
    two sections together with :func:`pair_config`."""
    cfg = _merge(defaults, {} if user is None else user, path)
    if "scene" in cfg and "camera" in cfg:  # a whole synth config: camera pairs
        cp = f"{path}.camera" if path else "camera"
        _check_camera(cfg["camera"], cp)
        _check_scene(cfg["scene"], f"{path}.scene" if path else "scene", camera=cfg["camera"])
    elif "layouts" in cfg:
        _check_scene(cfg, path or "scene")
    elif "cfa_patterns" in cfg:
        _check_camera(cfg, path or "camera")
    if "seed" in cfg:
        check_seed(cfg["seed"])
    if "shard_size" in cfg:
        _check_number(cfg["shard_size"], "shard_size", 1, integer=True, what="an integer number of items")
    if "dtype" in cfg and cfg["dtype"] not in ("float32", "float64"):
        raise ValueError(f"dtype: expected float32 or float64, got {cfg['dtype']!r}")
    if "targets" in cfg:
        check_targets(cfg["targets"])
    return cfg


def pair_config(scene: dict | None, camera: dict | None) -> tuple[dict, dict]:
    """The merged, validated ``(scene, camera)`` configs of camera pairs (keys of :data:`SCENE_DEFAULTS` and
    :data:`CAMERA_DEFAULTS`): :func:`merge_config`'s checks of each section, and of the two together as ``isettorch
    synth`` checks them (even sizes, the layouts' minimum scene size with the margin, no ``scene.hfov_deg``: the
    sensor sets the field of view). ``CameraPairDataset``, ``PairStream`` and ``isettorch synth`` share it."""
    scene_cfg = _merge(SCENE_DEFAULTS, {} if scene is None else scene, "scene")
    camera_cfg = _merge(CAMERA_DEFAULTS, {} if camera is None else camera, "camera")
    _check_camera(camera_cfg, "camera")
    _check_scene(scene_cfg, "scene", camera=camera_cfg)
    return scene_cfg, camera_cfg


def load_config(path: str | Path) -> dict:
    """Read a YAML config (:func:`isettorch._yaml.load_yaml`: safe, YAML 1.2 floats such as ``1e-3``) and validate
    it against :data:`SYNTH_DEFAULTS`."""
    from .._yaml import load_yaml

    p = Path(path)
    try:
        data = load_yaml(p.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise ValueError(f"config: could not read YAML from {str(p)!r}: {err}") from err
    if isinstance(data, dict) and isinstance(data.get("camera"), dict) and "optics" in data["camera"]:
        from ..optics.factory import resolve_config_paths  # its files relative to the YAML's folder

        data["camera"] = {**data["camera"], "optics": resolve_config_paths(data["camera"]["optics"], p.parent)}
    return merge_config(data or {})


_DRAW = threading.local()


def uniform01(g: torch.Generator) -> float:
    """One float64 draw in [0, 1) from ``g``: the value of ``float(torch.rand((), generator=g, dtype=float64))``
    (the same state advance), through a per-thread reused 0-d tensor (half the per-call cost: no allocation)."""
    buf = getattr(_DRAW, "u", None)
    if buf is None:
        with torch.inference_mode(False):  # a normal tensor even when the first draw is under inference_mode
            buf = _DRAW.u = torch.empty((), dtype=torch.float64)
    return buf.uniform_(generator=g).item()


def randint_scalar(low: int, high: int, g: torch.Generator) -> int:
    """One integer in ``[low, high)`` from ``g``: the value of ``int(torch.randint(low, high, (), generator=g))``
    (``torch.randint`` is ``random_(low, high)`` on a fresh tensor), through a per-thread reused 0-d tensor."""
    buf = getattr(_DRAW, "i", None)
    if buf is None:
        with torch.inference_mode(False):  # (as above: an inference buffer refused every later in-place draw)
            buf = _DRAW.i = torch.empty((), dtype=torch.long)
    return buf.random_(low, high, generator=g).item()


@contextlib.contextmanager
def one_thread():
    """Run with one intra-op thread: some torch kernels (e.g. ``irfft2`` at some sizes, GEMM) round differently
    with more threads, and DataLoader workers always use one, so this keeps items bitwise identical in the
    main process and in workers (and costs nothing inside workers)."""
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -2, -3, -8  # glibc <malloc.h> mallopt


def tune_allocator() -> bool:
    """Keep large freed tensors in this process's heap (glibc ``mallopt``); returns whether it applied.

    By default glibc serves every allocation above 128 KiB with its own ``mmap`` and gives it back on free, so each
    fresh image-sized tensor page-faults on first touch (the kernel zeroes every page), and a freed heap top is
    trimmed. Generating a batch of camera pairs allocates and frees tens of MB of such temporaries. This sets
    ``M_MMAP_THRESHOLD`` to 32 MiB (glibc's maximum), ``M_TRIM_THRESHOLD`` to 1 GiB and ``M_TOP_PAD`` to 256 MiB:
    measured 7.1 -> 6.2 CPU ms per 128 x 128 pair (``benchmarks/THROUGHPUT.md``). It also sets ``M_ARENA_MAX`` to
    1, so that threads started afterwards allocate from the same (main) heap: glibc gives each new thread an arena
    of 64 MiB mmap'd heaps that these thresholds do not keep, so a :class:`~isettorch.data.PairStream` rendering on
    a worker thread page-faulted about 6x as often as on the main thread and ran 7 % slower (batch 64 at 128^2, one
    thread: 85,000 against 13,000 minor faults per 256 pairs; with one arena both 7,000-19,000 and the same rate).
    The cost: memory freed inside the process is kept for reuse (its resident size stays near its peak), and
    threads share one allocator lock (torch allocates few, large blocks; Python's small objects do not use it).
    ``CameraPairDataset`` applies it in DataLoader worker processes (``tune_worker_allocator=True``); call it
    yourself, before starting threads, to get it in a process that generates data itself (a ``PairStream`` on a
    CPU).
    No-op (returns False) where the C library is not glibc.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * 2**20)
    ok &= mallopt(_M_TRIM_THRESHOLD, 2**30)
    ok &= mallopt(_M_TOP_PAD, 256 * 2**20)
    ok &= mallopt(_M_ARENA_MAX, 1)
    return bool(ok)
