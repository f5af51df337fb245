"""Spectral OpenEXR in the layout of Fichet, Pacanowski & Wilkie, "An OpenEXR layout for spectral images",
JCGT 10(3), 2021.

Layout (as in the paper and its reference implementation, and colour-science's ``fichet2021`` module):

* one FLOAT channel per wavelength; emissive spectra are Stokes component 0 and named
  ``S0.<value><unit>`` and reflective ones ``T.<value><unit>``, with the value written with a **comma** as
  decimal separator (the dot separates layers in OpenEXR), e.g. ``S0.550,000000nm``;
* a header attribute ``spectralLayoutVersion`` = ``"1.0"``, and ``emissiveUnits`` (``"W.m^-2.sr^-1"``:
  spectral radiance per nm) for emissive images;
* isettorch adds the scene geometry as header attributes ``isettorch.hfov_deg``, ``isettorch.distance_m``
  (floats: the OpenEXR package stores a Python float as a 32-bit attribute, so they come back to about 6e-8
  relative, 1.2 m as 1.2000000477 m), ``isettorch.radianceUnits`` (string) and, when the scene has one,
  ``isettorch.illuminant`` (float vector, same units as the channels).

Values are stored as float32, so a float32 array written and read back is bitwise identical.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from .. import constants, spectral
from .._checks import as_tensor, check_nanometres, check_wavelengths, narrow_float
from .._files import write_atomic

__all__ = ["write_spectral_exr", "read_spectral_exr", "write_scene_exr", "read_scene_exr", "channel_name",
           "parse_channel_name"]

LAYOUT_VERSION = "1.0"
EMISSIVE_UNITS = "W.m^-2.sr^-1"
_PREFIX_EXP = {"Y": 24, "Z": 21, "E": 18, "P": 15, "T": 12, "G": 9, "M": 6, "k": 3, "h": 2, "da": 1, "": 0, "d": -1,
               "c": -2, "m": -3, "u": -6, "n": -9, "p": -12, "f": -15, "a": -18, "z": -21, "y": -24}
# Fichet et al. 2021, sec. 3: <component>.<number with ',' decimal separator><SI prefix><m | Hz>
_CHANNEL = re.compile(r"^(S0|S1|S2|S3|T)\.(\d*,?\d*(?:[eE][-+]?\d+)?)(da|[YZEPTGMkhdcmunpfazy])?(m|Hz)$")


def channel_name(wavelength_nm: float, component: str = "S0") -> str:
    """Fichet et al. channel name of a wavelength: ``channel_name(550) == 'S0.550,000000nm'``."""
    return f"{component}.{float(wavelength_nm):.6f}".replace(".", ",").replace(",", ".", 1) + "nm"


def parse_channel_name(name: str) -> tuple[str, float] | None:
    """``(component, wavelength_nm)`` of a Fichet et al. channel name, or None for other channels."""
    m = _CHANNEL.match(name)
    if m is None or m.group(2) in ("", ","):
        return None
    value = float(m.group(2).replace(",", "."))
    exp = _PREFIX_EXP[m.group(3) or ""]
    if m.group(4) == "m":  # exact for nm (10 ** 0)
        return m.group(1), value * 10 ** (exp + 9) if exp + 9 >= 0 else value / 10 ** -(exp + 9)
    if value <= 0:
        return None
    return m.group(1), constants.SPEED_OF_LIGHT_M_PER_S / (value * 10.0**exp) * 1e9  # frequency (Hz) -> nm


def _as_numpy_f32(data, name: str) -> np.ndarray:
    a = data.detach().cpu().numpy() if isinstance(data, torch.Tensor) else np.asarray(data)
    if np.iscomplexobj(a):  # (written as its real part, with a warning only)
        raise ValueError(f"{name}: expected real values, got a complex cube")
    if a.ndim != 3:
        raise ValueError(f"{name}: expected a cube [L, H, W], got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: expected finite values")
    return np.ascontiguousarray(narrow_float(a, np.float32, name, underflow=True))


def write_spectral_exr(path, data, wavelengths_nm, *, component: str = "S0", attributes: dict | None = None,
                       compression: str = "zip") -> Path:
    """Write a spectral cube ``[L, H, W]`` (float32) with one channel per wavelength (Fichet et al. 2021).

    Args:
        component: ``'S0'`` (emissive, adds ``emissiveUnits``) or ``'T'`` (reflective / transmissive).
        attributes: extra header attributes (str, float, int or float arrays).
        compression: ``'zip'``, ``'piz'`` or ``'none'`` (all lossless for float32).
    """
    import OpenEXR

    a = _as_numpy_f32(data, "data")
    w = as_tensor(wavelengths_nm, "wavelengths_nm", dtype=torch.float64).detach().cpu().numpy().reshape(-1)
    if w.size != a.shape[0]:
        raise ValueError(f"wavelengths_nm: expected {a.shape[0]} wavelengths (one per band), got {w.size}")
    # (metres or micrometres were written as channels of 0-1 nm; NaN or negative ones as names its reader refuses)
    check_wavelengths(torch.as_tensor(np.sort(w)), "wavelengths_nm")
    check_nanometres(w, "wavelengths_nm")
    if np.any(np.diff(w) <= 0):  # (the reader returns the bands increasing: a per-band attribute, e.g. the
        # illuminant, written in another order came back out of step with them)
        raise ValueError(f"wavelengths_nm: expected increasing wavelengths (one per band, in the data's order), got "
                         f"{w.tolist()}")
    if component not in ("S0", "T"):
        raise ValueError(f"component: expected 'S0' (emissive) or 'T' (reflective), got {component!r}")
    comp = {"zip": OpenEXR.ZIP_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION, "none": OpenEXR.NO_COMPRESSION}
    if compression not in comp:
        raise ValueError(f"compression: expected one of {sorted(comp)}, got {compression!r}")
    names = [channel_name(x, component) for x in w]
    if len(set(names)) != len(names):
        raise ValueError(f"wavelengths_nm: expected distinct wavelengths (to 1e-6 nm), got {w.tolist()}")
    header = {"compression": comp[compression], "type": OpenEXR.scanlineimage,
              "spectralLayoutVersion": LAYOUT_VERSION}
    if component == "S0":
        header["emissiveUnits"] = EMISSIVE_UNITS
    header.update(attributes or {})
    p = Path(path)
    # under a temporary name, moved into place when whole (a failure leaves none)
    write_atomic(p, lambda tmp: OpenEXR.File(header, {n: a[i] for i, n in enumerate(names)}).write(str(tmp)))
    return p


def _exr_channels(p: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """An OpenEXR file's header and its channels, each under its own name (half and float as stored, UINT as
    float64: exact, where float32 holds integers exactly only to 2^24). Opened with ``separate_channels``: the
    package's default groups R, G, B(, A) into one array and refused a file mixing half and float channels
    ("cannot coalesce"). An unreadable file raises a ValueError naming it."""
    import OpenEXR

    try:
        f = OpenEXR.File(str(p), separate_channels=True)
        header = dict(f.header())
        chans = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
        parts = len(f.parts)
    except Exception as err:  # OpenEXR raises RuntimeError / others for corrupt or truncated files
        raise ValueError(f"path: {str(p)!r} is not a readable OpenEXR file ({err})") from err
    if parts > 1:  # (part 0 alone was read, the others dropped without a word)
        raise ValueError(f"path: {str(p)!r} is a multi-part OpenEXR file ({parts} parts); expected one part (save "
                         f"the image as a single-part file)")
    data, shown = header.get("dataWindow"), header.get("displayWindow")
    if data is not None and shown is not None and not all(
            np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(data, shown, strict=True)):
        # (the data window's pixels were returned as the image, its place in the display window dropped: a crop
        # or an overscan read as the whole picture)
        win = [tuple(int(v) for v in np.asarray(c)) for c in (*data, *shown)]
        raise ValueError(f"path: {str(p)!r} has a data window {win[0]}-{win[1]} that is not its display window "
                         f"{win[2]}-{win[3]} (x, y); expected the two to be equal (crop or pad the image to its "
                         f"display window first)")
    return header, {k: a.astype(np.float64) if a.dtype.kind in "ui" else a for k, a in chans.items()}


def read_spectral_exr(path) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Read a Fichet et al. spectral EXR: ``(data [L, H, W] float32, wavelengths_nm [L] float64, header)``.

    Emissive (``S0``) channels are returned when present, else reflective (``T``) ones; bands are sorted by
    wavelength. Raises ValueError for unreadable files and files without spectral channels.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"path: no such file {str(p)!r}")
    header, chans = _exr_channels(p)
    parsed = {}
    for name in chans:
        r = parse_channel_name(name)
        if r is not None:
            parsed.setdefault(r[0], []).append((r[1], name))
    comp = "S0" if "S0" in parsed else "T" if "T" in parsed else None
    if comp is None:
        raise ValueError(f"path: {str(p)!r} has no spectral channels in the Fichet et al. 2021 layout "
                         f"(names like 'S0.550,000000nm'); channels are {sorted(chans)[:8]}")
    bands = sorted(parsed[comp])
    # nanometres, each once (channels of 0.4-0.7 loaded a scene of 0.4-0.7 nm light; 'S0.550nm' beside
    # 'S0.550,000000nm' was a grid that failed later, naming no file)
    check_nanometres([w for w, _ in bands], f"path: {str(p)!r}'s {comp} channels")
    same = [(a[1], b[1]) for a, b in zip(bands, bands[1:]) if a[0] == b[0]]
    if same:
        raise ValueError(f"path: {str(p)!r} has two {comp} channels at one wavelength: {same[0][0]!r} and "
                         f"{same[0][1]!r}")
    data = np.stack([chans[n].astype(np.float32, copy=False) for _, n in bands])
    header["component"] = comp
    return torch.from_numpy(data), torch.tensor([w for w, _ in bands], dtype=torch.float64), header


def write_scene_exr(path, scene, index: int | None = None, *, compression: str = "zip") -> Path | list[Path]:
    """Write a `Scene` as emissive spectral EXR: radiance in W/sr/m^2/nm (float32), with its FOV, distance and
    (if any) illuminant in the header.

    ``index``: write that sample only. Otherwise a one-sample scene is written to ``path``, and a batch one file
    per sample through an ``{i}`` field in ``path`` (``"scene_{i:03d}.exr"``; returns the list of paths); a
    batch without one raises (it used to write sample 0 only).
    """
    from ..scene import Scene

    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a Scene, got {type(scene).__name__}")
    template = str(path)
    if index is None:
        if "{i" in template:
            return [write_scene_exr(template.format(i=i), scene, i, compression=compression)
                    for i in range(scene.batch_size)]
        if scene.batch_size > 1:
            raise ValueError(f"scene: a batch of {scene.batch_size}; give index=k for one sample, or a path with an "
                             "{i} field (e.g. 'scene_{i:03d}.exr') to write one file per sample")
        index = 0
    if not -scene.batch_size <= index < scene.batch_size:
        raise ValueError(f"index: expected a sample index in [0, {scene.batch_size}), got {index}")
    s = scene[index]
    energy = spectral.photons_to_energy(s.photons[0].to(torch.float64), s.wavelengths_nm.to(torch.float64), dim=0)
    attrs = {"isettorch.hfov_deg": float(s.hfov_deg[0]), "isettorch.distance_m": float(s.distance_m[0]),
             "isettorch.radianceUnits": "W.sr^-1.m^-2.nm^-1"}
    if s.name:
        attrs["isettorch.name"] = s.name
    if s.illuminant_photons is not None:
        ill = spectral.photons_to_energy(s.illuminant_photons[0].to(torch.float64),
                                         s.wavelengths_nm.to(torch.float64), dim=0)
        attrs["isettorch.illuminant"] = narrow_float(ill.cpu().numpy(), np.float32, "scene.illuminant_photons",
                                                     underflow=True)
    return write_spectral_exr(path, energy, s.wavelengths_nm, component="S0", attributes=attrs,
                              compression=compression)


def read_scene_exr(path, *, hfov_deg: float | None = None, distance_m: float | None = None, dtype=torch.float32):
    """Read an emissive spectral EXR as a `Scene` (radiance W/sr/m^2/nm -> photons/s/sr/m^2/nm).

    FOV and distance come from the arguments, else from the file's ``isettorch.*`` attributes, else ISETCam's
    defaults (10 deg, 1.2 m; recorded in ``metadata['defaulted']``).
    """
    from ..scene import Scene

    data, w, header = read_spectral_exr(path)
    if header["component"] != "S0":
        raise ValueError(f"path: {str(path)!r} holds reflective (T) channels, not emissive radiance (S0)")
    units = header.get("emissiveUnits")
    # per nm either way (the layout's channels are per wavelength; tinyexr writes the '.nm^-1'): a file in mW was
    # read as W, 1000x too bright
    if units is not None and "".join(str(units).split()) not in (EMISSIVE_UNITS, EMISSIVE_UNITS + ".nm^-1"):
        raise ValueError(f"path: {str(path)!r} gives its radiance in {units!r}; expected {EMISSIVE_UNITS!r} (per "
                         f"nm, or {EMISSIVE_UNITS + '.nm^-1'!r}, or no emissiveUnits attribute)")
    defaulted = []
    hfov = hfov_deg if hfov_deg is not None else header.get("isettorch.hfov_deg")
    if hfov is None:
        hfov, defaulted = 10.0, defaulted + ["hfov_deg"]
    dist = distance_m if distance_m is not None else header.get("isettorch.distance_m")
    if dist is None:
        dist, defaulted = 1.2, defaulted + ["distance_m"]
    if not bool(torch.isfinite(data).all()) or bool((data < 0).any()):
        raise ValueError(f"path: {str(path)!r} holds negative or non-finite radiance in its S0 channels (minimum "
                         f"{float(data.min()):.6g} W/sr/m^2/nm); a scene's radiance is >= 0")
    photons = spectral.energy_to_photons(data.to(torch.float64), w, dim=0)
    ill = header.get("isettorch.illuminant")
    ill_p = None
    if ill is not None:
        ill = np.asarray(ill, dtype=float).reshape(-1)
        if ill.size != w.numel():
            raise ValueError(f"path: {str(path)!r} has an isettorch.illuminant attribute of {ill.size} values for "
                             f"{w.numel()} wavelengths")
        ill_p = spectral.energy_to_photons(torch.as_tensor(ill, dtype=torch.float64), w, dim=0).to(dtype)
    meta = {"source": str(path), "defaulted": defaulted, "emissiveUnits": header.get("emissiveUnits")}
    try:
        return Scene(photons.to(dtype)[None], w.to(dtype), name=str(header.get("isettorch.name", Path(path).stem)),
                     metadata=meta, hfov_deg=float(hfov), distance_m=float(dist), illuminant_photons=ill_p)
    except ValueError as err:  # a header value the scene refuses (its field named in err): say which file
        raise ValueError(f"path: {str(path)!r}: {err}") from err
