"""Loaders for public hyperspectral image sets (the files must already be on disk; nothing is downloaded).

* **CAVE** (Yasuma et al., "Generalized assorted pixel camera", IEEE TIP 19(9), 2010): one 16-bit
  grayscale PNG per band, ``<name>_ms_01.png`` ... ``<name>_ms_31.png`` for 400, 410, ..., 700 nm, in a folder
  ``<name>_ms/``. The values are reflectance-like (relative to a white reference), so the scene is
  rendered under an illuminant (default D65).
* **KAIST** (Choi et al., "High-quality hyperspectral reconstruction using a spectral prior", ACM TOG 36(6),
  2017): OpenEXR with one channel per band; channel names carry the wavelength (``'420'``, ``'w420nm'``,
  ``'S0.420,000000nm'``). Values are relative spectral radiance.
* **ICVL** (Arad & Ben-Shahar, ECCV 2016) and **ARAD / NTIRE** (Arad et al., NTIRE 2020/2022 challenges):
  MATLAB v7.3 (HDF5) files holding ``rad`` (ICVL) or ``cube`` (ARAD), ``(rows, cols, bands)`` in MATLAB
  order, and ``bands`` (nm). Values are relative spectral radiance.

Relative radiances are taken in energy units, converted to photons and scaled to ``mean_luminance_cd_m2``
(ISETCam's ``sceneAdjustLuminance``; 100 cd/m^2 by default).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from .. import spectral
from .._checks import check_nanometres

__all__ = ["load_cave", "load_kaist", "load_icvl", "load_arad"]

_CAVE_BAND = re.compile(r"_ms_(\d{2})\.png$", re.IGNORECASE)


def _radiance_scene(energy: np.ndarray, wave: np.ndarray, name: str, source: str, hfov_deg: float | None,
                    mean_luminance_cd_m2: float | None, dtype, illuminant_photons=None, distance_m=None):
    """The scene of a radiance cube; a field of view or distance not given is ISETCam's default (10 deg, 1.2 m),
    recorded in ``metadata['defaulted']`` as the EXR and ISETCam readers record theirs (the files hold neither)."""
    from ..scene import Scene

    e = torch.as_tensor(np.ascontiguousarray(energy), dtype=torch.float64)
    if not torch.isfinite(e).all() or (e < 0).any():
        raise ValueError(f"{source}: expected finite non-negative values, got min {float(e.min()):.6g}")
    w = torch.as_tensor(wave, dtype=torch.float64)
    photons = spectral.energy_to_photons(e, w, dim=0)[None]
    defaulted = [k for k, v in (("hfov_deg", hfov_deg), ("distance_m", distance_m)) if v is None]
    s = Scene(photons.to(dtype), w.to(dtype), name=name, metadata={"source": source, "defaulted": defaulted},
              hfov_deg=10.0 if hfov_deg is None else hfov_deg, distance_m=1.2 if distance_m is None else distance_m,
              illuminant_photons=illuminant_photons)
    if mean_luminance_cd_m2 is not None:
        s = s.set_mean_luminance(mean_luminance_cd_m2)
    return s


def load_cave(folder, *, illuminant: str = "D65", hfov_deg: float | None = None, distance_m: float | None = None,
              mean_luminance_cd_m2: float = 100.0, dtype=torch.float32):
    """Read a CAVE scene folder (PNG per band) as a `Scene` lit by ``illuminant``."""
    from .images import _read_png

    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"folder: no such directory {str(root)!r}")
    # any case of '.png' (the band names match in any case); not macOS's '._' resource forks and __MACOSX copies of
    # an unzipped archive, which doubled every band number
    files = sorted((int(m.group(1)), f) for f in root.rglob("*") if f.suffix.lower() == ".png"
                   and not f.name.startswith(".") and "__MACOSX" not in f.relative_to(root).parts
                   and (m := _CAVE_BAND.search(f.name)))
    if not files:
        raise ValueError(f"folder: {str(root)!r} holds no CAVE band images (<name>_ms_NN.png)")
    numbers = [n for n, _ in files]
    if numbers != list(range(1, 32)):  # CAVE's 31 bands, 400-700 nm (3 bands loaded as a 400-420 nm scene)
        raise ValueError(f"folder: expected consecutive CAVE bands 01..31 (400-700 nm in 10 nm steps), got "
                         f"{numbers}")
    bands = []
    for _, f in files:
        try:  # pypng, at the file's bit depth: Pillow read a 16-bit RGB(A) band as 8-bit (code 200 became 0)
            a = _read_png(f)[0]
        except (ValueError, OSError) as err:
            raise ValueError(f"{str(f)!r}: not a readable PNG ({type(err).__name__}: {err})") from err
        if a.shape[-1] >= 3 and not (np.array_equal(a[..., 0], a[..., 1]) and np.array_equal(a[..., 0], a[..., 2])):
            raise ValueError(f"{str(f)!r}: a CAVE band stored as RGB has equal channels (grey), this one's differ")
        a = a[..., 0]  # grey; a few CAVE bands are stored as RGB(A), whose channels are equal
        # the file's bit depth, not the data's maximum (a dark 16-bit band read as 8-bit was 257x too bright)
        bands.append(a.astype(np.float64) / (65535.0 if a.dtype == np.uint16 else 255.0))
    shapes = {b.shape for b in bands}
    if len(shapes) != 1:
        raise ValueError(f"folder: CAVE bands differ in size: {sorted(shapes)}")
    refl = np.stack(bands)
    wave = 400.0 + 10.0 * np.arange(refl.shape[0])
    w = torch.as_tensor(wave, dtype=torch.float64)
    ill_e = spectral.illuminant(illuminant, w, dtype=torch.float64)
    energy = refl * ill_e.numpy()[:, None, None]
    ill_p = spectral.energy_to_photons(ill_e, w, dim=0).to(dtype)
    name = files[0][1].name[: _CAVE_BAND.search(files[0][1].name).start()]
    return _radiance_scene(energy, wave, name, str(root), hfov_deg, mean_luminance_cd_m2, dtype, ill_p, distance_m)


_KAIST_NAME = re.compile(r"^w?(\d+(?:[.,]\d+)?)(?:nm)?$", re.IGNORECASE)


def load_kaist(path, *, hfov_deg: float | None = None, distance_m: float | None = None,
               mean_luminance_cd_m2: float = 100.0, dtype=torch.float32):
    """Read a KAIST hyperspectral EXR (one channel per band, wavelength in the channel name) as a `Scene`."""
    from .exr import _exr_channels, parse_channel_name

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"path: no such file {str(p)!r}")
    chans = _exr_channels(p)[1]
    bands = []
    for name, a in chans.items():
        fichet = parse_channel_name(name)
        if fichet is not None:
            bands.append((fichet[1], a))
            continue
        m = _KAIST_NAME.match(name)  # '420', '420nm', 'w420nm' ('frame_0512' was a 512 nm band)
        if m is not None:  # (every one: bands beyond 300-1100 nm were dropped without a word; nanometres checked below)
            bands.append((float(m.group(1).replace(",", ".")), a))
    if not bands:
        raise ValueError(f"path: {str(p)!r} has no channels named by wavelength (e.g. '420', 'w420nm'); "
                         f"channels are {sorted(chans)[:8]}")
    bands.sort(key=lambda x: x[0])
    wave = np.array([b[0] for b in bands])
    check_nanometres(wave, f"path: {str(p)!r}'s channel wavelengths")
    if np.any(np.diff(wave) <= 0):
        raise ValueError(f"path: duplicate band wavelengths {wave.tolist()}")
    cube = np.stack([b[1].astype(np.float64) for b in bands])
    return _radiance_scene(cube, wave, p.stem, str(p), hfov_deg, mean_luminance_cd_m2, dtype, distance_m=distance_m)


def _load_h5_cube(path, keys: tuple[str, ...]):
    import h5py

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"path: no such file {str(p)!r}")
    try:
        with h5py.File(str(p), "r") as f:
            key = next((k for k in keys if k in f), None)
            if key is None:
                raise ValueError(f"path: {str(p)!r} holds none of the datasets {list(keys)}; it has {sorted(f.keys())}")
            cube = np.asarray(f[key][()], dtype=np.float64)
            bands = np.asarray(f["bands"][()], dtype=np.float64).reshape(-1) if "bands" in f else None
    except ValueError:
        raise
    except Exception as err:  # h5py raises OSError for truncated or non-HDF5 files
        raise ValueError(f"path: {str(p)!r} is not a readable MATLAB v7.3 / HDF5 file ({err})") from err
    if cube.ndim != 3:
        raise ValueError(f"{key}: expected a 3-D cube, got shape {cube.shape}")
    # MATLAB (rows, cols, bands) is stored by HDF5 as (bands, cols, rows)
    cube = np.transpose(cube, (0, 2, 1))
    if bands is None:
        if cube.shape[0] != 31:  # 519 bands were read as 400-5580 nm
            raise ValueError(f"bands: {str(p)!r} has no 'bands' dataset, and {key} has {cube.shape[0]} bands, not the "
                             f"31 of ICVL's and ARAD's 400:10:700 nm that it would be read as")
        bands = 400.0 + 10.0 * np.arange(cube.shape[0])  # ICVL / ARAD's grid (Arad & Ben-Shahar 2016; NTIRE 2020)
    if bands.size != cube.shape[0]:
        raise ValueError(f"bands: expected {cube.shape[0]} wavelengths to match {key}, got {bands.size}")
    check_nanometres(bands, f"bands ({str(p)!r})")  # (0.4-0.7 um read "the scene is black", or a 0.4 nm scene)
    return p, cube, bands


def load_icvl(path, *, hfov_deg: float | None = None, distance_m: float | None = None,
              mean_luminance_cd_m2: float = 100.0, dtype=torch.float32):
    """Read an ICVL (``rad`` + ``bands``) or ARAD (``cube`` + ``bands``) MATLAB v7.3 file as a `Scene`. A file without
    ``bands`` is read on their 400:10:700 nm grid if it has 31 bands (else an error naming ``bands``)."""
    p, cube, bands = _load_h5_cube(path, ("rad", "cube"))
    return _radiance_scene(cube, bands, p.stem, str(p), hfov_deg, mean_luminance_cd_m2, dtype,
                           distance_m=distance_m)


load_arad = load_icvl
