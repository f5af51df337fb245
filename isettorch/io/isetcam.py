"""ISETCam files: scenes saved as MATLAB files, and the parity cases of ``isetcam-parity/FORMAT.md``.

Scenes (``save(fname, 'scene')`` / ``sceneSaveData``):

ISETCam's scene struct (``sceneCreate``): ``scene.data.photons`` ``(rows, cols, wave)`` in
photons/s/sr/m^2/nm, ``scene.spectrum.wave`` (nm), ``scene.wAngular`` (horizontal FOV, deg),
``scene.distance`` (m), ``scene.name``, and optionally ``scene.illuminant.data.photons`` (``[wave]`` or
``(rows, cols, wave)`` for spatially varying illuminants). Older files store compressed photons
(``ieCompressData``): integer codes with ``scene.data.dmin``, ``dmax`` and ``bitDepth``, decoded as
``dmin + code (dmax - dmin) / (2^bitDepth - 1)`` (ISETCam ``ieUncompressData``).

MATLAB v5/v7 files are read with ``scipy.io.loadmat``; v7.3 (HDF5) files with ``h5py``.

Parity cases (``.npz``, FORMAT.md sections 1-3): :func:`read_parity_case` / :func:`write_parity_case` (no
pickle), and the isettorch objects a case describes: :func:`case_cfa`, :func:`case_adc_bits`,
:func:`case_sensor` (its parameters with ``ISETCAM_CONVENTIONS``), :func:`case_optical_image` (its own OI) and
:func:`case_scene_oi` (our ISETCam-compatible OI of its scene, :func:`isettorch.optics.isetcam.compute_oi`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["read_isetcam_scene", "read_parity_case", "write_parity_case", "case_cfa", "case_adc_bits", "case_sensor",
           "case_optical_image", "case_scene_oi", "SCENE_KEYS"]


def _unwrap(x):
    """scipy (squeeze_me=False) wraps structs, strings and scalars in 1x1 arrays; numeric arrays keep shape."""
    while isinstance(x, np.ndarray) and x.dtype == object and x.size == 1:
        x = x.reshape(-1)[0]
    if isinstance(x, np.ndarray) and x.dtype.kind in "US" and x.size == 1:
        return str(x.reshape(-1)[0])
    return x


def _scalar(x):
    x = _unwrap(x)
    return None if x is None else float(np.asarray(x, dtype=float).reshape(-1)[0])


def _field(obj, name: str):
    obj = _unwrap(obj)
    if obj is None:
        return None
    if isinstance(obj, dict):
        return _unwrap(obj.get(name))
    if hasattr(obj, "_fieldnames"):
        return _unwrap(getattr(obj, name)) if name in obj._fieldnames else None
    return None


def _load_v5(p: Path) -> dict:
    import scipy.io

    return scipy.io.loadmat(str(p), squeeze_me=False, struct_as_record=False)


class _H5Struct(dict):
    """A v7.3 MATLAB struct read from HDF5 as nested dicts, arrays transposed back to MATLAB order."""


def _load_h5(p: Path) -> dict:
    import h5py

    def conv(node):
        if isinstance(node, h5py.Group):
            return _H5Struct({k: conv(node[k]) for k in node.keys() if not k.startswith("#")})
        a = np.asarray(node[()])
        if node.attrs.get("MATLAB_class", b"") in (b"char", "char"):
            return "".join(chr(c) for c in a.flatten())
        return a.T  # HDF5 stores MATLAB's column-major arrays transposed

    with h5py.File(str(p), "r") as f:
        return {k: conv(f[k]) for k in f.keys() if not k.startswith("#")}


def read_isetcam_scene(path, *, variable: str = "scene", dtype=torch.float32):
    """Read an ISETCam scene ``.mat`` as a `Scene`.

    Args:
        path: the .mat file.
        variable: name of the struct in the file (``'scene'`` for ``save(fname, 'scene')``).
    Raises:
        ValueError: unreadable or truncated file, missing struct or fields, inconsistent shapes.
    """
    from ..scene import Scene

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"path: no such file {str(p)!r}")
    import h5py

    try:
        mat = _load_h5(p) if h5py.is_hdf5(str(p)) else _load_v5(p)  # v7.3 files are HDF5
    except Exception as err:
        raise ValueError(f"path: {str(p)!r} is not a readable MATLAB file ({type(err).__name__}: {err})") from err
    scene = _unwrap(mat.get(variable))
    if scene is None:
        names = sorted(k for k in mat if not k.startswith("__"))
        raise ValueError(f"variable: no {variable!r} in {str(p)!r}; it holds {names}")
    data = _field(scene, "data")
    photons = _field(data, "photons")
    wave = _field(_field(scene, "spectrum"), "wave")
    if photons is None or wave is None:
        raise ValueError(f"path: {str(p)!r}: expected scene.data.photons and scene.spectrum.wave (ISETCam layout)")
    photons = np.asarray(photons)
    wave = np.atleast_1d(np.asarray(wave, dtype=float)).reshape(-1)
    if photons.ndim == 2 and wave.size == 1:
        photons = photons[:, :, None]
    if photons.ndim != 3 or photons.shape[2] != wave.size:
        raise ValueError(f"scene.data.photons: expected (rows, cols, {wave.size}) to match scene.spectrum.wave, "
                         f"got {photons.shape}")
    if np.issubdtype(photons.dtype, np.integer):  # ieCompressData
        dmin, dmax, bits = (_field(data, k) for k in ("dmin", "dmax", "bitDepth"))
        if dmin is None or dmax is None:
            raise ValueError("scene.data: integer (compressed) photons need dmin and dmax (ISETCam ieCompressData)")
        bits = 16 if bits is None else int(_scalar(bits))
        dmin, dmax = _scalar(dmin), _scalar(dmax)
        photons = dmin + photons.astype(np.float64) * (dmax - dmin) / (2**bits - 1)
    hfov = _field(scene, "wAngular")
    dist = _field(scene, "distance")
    ill = _field(_field(_field(scene, "illuminant"), "data"), "photons")
    ill_t = None
    if ill is not None:
        ill = np.asarray(ill, dtype=float)
        if ill.size == wave.size:
            ill_t = torch.as_tensor(ill.reshape(-1), dtype=dtype)
        # spatially varying illuminants (rows, cols, wave) are kept in metadata only
    name = _field(scene, "name")
    cube = torch.as_tensor(np.ascontiguousarray(np.transpose(photons, (2, 0, 1))), dtype=dtype)[None]
    meta = {"source": str(p), "format": "isetcam"}
    if ill is not None and ill_t is None:
        meta["illuminant_photons_map"] = torch.as_tensor(np.transpose(ill, (2, 0, 1)).copy(), dtype=dtype)
    return Scene(cube, torch.as_tensor(wave, dtype=dtype), name=str(name) if name is not None else p.stem,
                 metadata=meta, hfov_deg=10.0 if hfov is None else _scalar(hfov),
                 distance_m=1.2 if dist is None else _scalar(dist), illuminant_photons=ill_t)


# --- parity cases (isetcam-parity/FORMAT.md) ------------------------------------------------------------------

SCENE_KEYS = ("scene_photons", "scene_hfov_deg", "scene_distance_m", "optics_f_number", "optics_focal_length_m")


def read_parity_case(path) -> dict:
    """A parity case as a dict of NumPy values (``np.load(..., allow_pickle=False)``: no object arrays).

    Raises:
        ValueError: the file is missing or not a readable ``.npz``.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"path: no such parity case {str(p)!r}")
    try:
        with np.load(p, allow_pickle=False) as d:
            return {k: d[k] for k in d.files}
    except (OSError, ValueError) as err:
        raise ValueError(f"path: {str(p)!r} is not a readable parity case (.npz): {err}") from err


def write_parity_case(path, case: dict) -> None:
    """Write a parity case (``np.savez``); values must be NumPy-convertible without object arrays (FORMAT.md 2)."""
    arrays = {}
    for k, v in case.items():
        a = np.asarray(v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else v)
        if a.dtype == object:
            raise ValueError(f"case[{k!r}]: expected a numeric or string array, got an object array")
        arrays[k] = a
    np.savez(path, **arrays)


def case_cfa(case: dict):
    """The case's CFA: the pattern (``sensor_cfa_pattern``, 1-based) over the filter order of
    ``sensor_filter_names``, letters from ``sensor_filter_letters`` (or the names' first letters); the full
    filter names become the channel names when the letters are not distinct known CFA letters."""
    from ..sensor.cfa import CFA, KNOWN_LETTERS

    names = [str(n) for n in np.atleast_1d(case["sensor_filter_names"])]
    if "sensor_filter_letters" in case:
        letters = list(str(case["sensor_filter_letters"]).upper())
    else:
        letters = [n[:1].upper() for n in names]
    if len(letters) != len(names) or len(set(letters)) != len(letters) or \
            any(x not in KNOWN_LETTERS for x in letters):
        letters = names  # fall back to the full filter names as channel names
    if "sensor_cfa_pattern" in case:
        pat = np.atleast_2d(np.asarray(case["sensor_cfa_pattern"], dtype=np.int64))
        if pat.min() < 1 or pat.max() > len(names):
            raise ValueError(f"sensor_cfa_pattern: expected 1-based indices into {len(names)} filters, got {pat}")
        cell = [[letters[i - 1] for i in row] for row in pat]
        cfa = CFA(cell, channel_names=letters)
        s = str(case.get("sensor_cfa", ""))
        if s and all(len(x) == 1 for x in letters) and cfa.pattern != s.upper():
            raise ValueError(f"sensor_cfa: {s!r} disagrees with sensor_cfa_pattern ({cfa.pattern!r})")
        return cfa
    return CFA(str(case["sensor_cfa"]), channel_names=letters)


def case_adc_bits(case: dict) -> int | None:
    """ADC bits from ``sensor_quantization`` ('analog' or '10', '10 bit'), else ``sensor_quantization_bits``;
    None for an analog sensor."""
    import re

    q = str(case.get("sensor_quantization", "")).strip().lower()
    if q == "analog":
        return None
    m = re.search(r"\d+", q)
    if m:
        return int(m.group()) or None
    if "sensor_quantization_bits" in case:
        return int(case["sensor_quantization_bits"]) or None
    if q:
        raise ValueError(f"sensor_quantization: expected 'analog' or a bit count such as '10', got {q!r}")
    return None


def case_sensor(case: dict, preblur_size: int | None = None):
    """A :class:`~isettorch.sensor.Sensor` with the case's parameters and ISETCam's conventions
    (``ISETCAM_CONVENTIONS``: pre-blur + point sampling, gain divides, ADC without clamp), noise off, volts out."""
    from ..sensor import ISETCAM_CONVENTIONS, Sensor, SpectralQE

    cfa = case_cfa(case)
    wave = torch.as_tensor(case["wavelengths_nm"], dtype=torch.float64).reshape(-1)
    qe = torch.as_tensor(case["sensor_spectral_qe"], dtype=torch.float64).reshape(cfa.num_channels, -1)
    return Sensor(
        rows=int(case["sensor_rows"]), cols=int(case["sensor_cols"]),
        pixel_size_m=float(case["sensor_pixel_size_m"]), fill_factor=float(case["sensor_fill_factor"]), cfa=cfa,
        spectral_qe=SpectralQE(qe, wave, cfa.channel_names),
        conversion_gain_v_per_e=float(case["sensor_conversion_gain_v_per_e"]),
        voltage_swing_v=float(case["sensor_voltage_swing_v"]), exposure_s=float(case["sensor_exposure_s"]),
        analog_gain=float(case.get("sensor_analog_gain", 1.0)),
        analog_offset_v=float(case.get("sensor_analog_offset", 0.0)), adc_bits=case_adc_bits(case),
        shot_noise="off", preblur_size=preblur_size, output_units="volts", name=str(case.get("case_name", "")),
        **ISETCAM_CONVENTIONS,
    )


def case_optical_image(case: dict):
    """The case's own optical image (``oi_photons``) as an :class:`~isettorch.optics.OpticalImage` (float64)."""
    from ..optics.optical_image import OpticalImage

    return OpticalImage(torch.as_tensor(case["oi_photons"], dtype=torch.float64)[None],
                        torch.as_tensor(case["wavelengths_nm"], dtype=torch.float64).reshape(-1),
                        sample_spacing_m=float(case["oi_sample_spacing_m"]),
                        pad_rows=int(case.get("oi_pad_rows", 0)), pad_cols=int(case.get("oi_pad_cols", 0)),
                        validate=False)


def case_scene_oi(case: dict, **kwargs):
    """Our ISETCam-compatible OI of the case's scene and optics (:func:`isettorch.optics.isetcam.compute_oi`,
    float64). ``kwargs`` go to ``compute_oi`` (e.g. ``return_details=True``).

    Raises:
        KeyError: the case lacks one of :data:`SCENE_KEYS`.
    """
    from ..optics.isetcam import compute_oi

    missing = [k for k in SCENE_KEYS if k not in case]
    if missing:
        raise KeyError(f"case lacks {', '.join(missing)}")
    off = "skip" if str(case.get("optics_offaxis", "cos4th")).lower() in ("skip", "none") else "cos4th"
    trans = case.get("optics_transmittance")
    return compute_oi(torch.as_tensor(case["scene_photons"], dtype=torch.float64),
                      torch.as_tensor(case["wavelengths_nm"], dtype=torch.float64).reshape(-1),
                      float(case["scene_hfov_deg"]), float(case["scene_distance_m"]), float(case["optics_f_number"]),
                      float(case["optics_focal_length_m"]),
                      None if trans is None else torch.as_tensor(trans, dtype=torch.float64).reshape(-1),
                      offaxis=off, **kwargs)
