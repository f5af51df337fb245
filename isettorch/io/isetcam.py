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
pickle); :func:`check_parity_case` checks a case's keys (:data:`REQUIRED`, FORMAT.md section 3), types and shapes,
reading values as MATLAB exports also write them (scalars as 1x1 arrays, strings as char arrays, cells or bytes);
and the isettorch objects a case describes: :func:`case_cfa`, :func:`case_adc_bits`,
:func:`case_sensor` (its parameters with ``ISETCAM_CONVENTIONS``), :func:`case_optical_image` (its own OI) and
:func:`case_scene_oi` (our ISETCam-compatible OI of its scene, :func:`isettorch.optics.isetcam.compute_oi`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from .._checks import check_nanometres
from .._files import write_atomic

__all__ = ["read_isetcam_scene", "read_parity_case", "check_parity_case", "write_parity_case", "case_cfa",
           "case_adc_bits", "case_sensor", "case_spectral_qe", "case_offaxis", "case_regrid_kernel",
           "case_optical_image", "case_scene_oi", "REQUIRED", "SCENE_KEYS", "NOISE_KEYS", "OFFAXIS"]


def _unwrap(x):
    """scipy (squeeze_me=False) wraps structs, strings and scalars in 1x1 arrays; numeric arrays keep shape."""
    while isinstance(x, np.ndarray) and x.dtype == object and x.size == 1:
        x = x.reshape(-1)[0]
    if isinstance(x, np.ndarray) and x.dtype.kind in "US" and x.size == 1:
        return str(x.reshape(-1)[0])
    return x


def _mat_scalar(x):
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
        if node.attrs.get("MATLAB_empty", 0):  # MATLAB stores an empty value as its dimensions, e.g. uint64 [0 0]
            return "" if node.attrs.get("MATLAB_class", b"") in (b"char", "char") else np.empty((0, 0))
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

    Without ``wAngular`` / ``distance`` the scene has ISETCam's defaults, 10 deg and 1.2 m (listed in
    ``metadata['defaulted']``). An ISETCam optical image or sensor (``type`` other than ``'scene'``) is refused.

    Raises:
        ValueError: unreadable or truncated file, missing struct or fields, inconsistent shapes, an illuminant on
            other wavelengths than the scene's.
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
    kind = _field(scene, "type")
    kind = kind if isinstance(kind, str) and kind else None  # (MATLAB's '' is an empty array in a v5 file)
    if kind is not None and kind.lower() != "scene":  # (an optical image's irradiance was read as radiance)
        raise ValueError(f"variable: {variable!r} in {str(p)!r} is an ISETCam {kind!r}, not a scene (type 'scene')")
    data = _field(scene, "data")
    photons = _field(data, "photons")
    wave = _field(_field(scene, "spectrum"), "wave")
    if photons is None or wave is None:
        raise ValueError(f"path: {str(p)!r}: expected scene.data.photons and scene.spectrum.wave (ISETCam layout)")
    photons = np.asarray(photons)
    if photons.dtype.kind not in "fiu":  # (complex photons were read as their real part, with a warning only)
        raise ValueError(f"scene.data.photons: expected real numbers in {str(p)!r}, got {photons.dtype}")
    try:
        wave = np.atleast_1d(np.asarray(wave, dtype=float)).reshape(-1)
    except (TypeError, ValueError) as err:
        raise ValueError(f"scene.spectrum.wave: expected numbers (nm) in {str(p)!r}, got {_unwrap(wave)!r}") from err
    check_nanometres(wave, "scene.spectrum.wave")
    if photons.ndim == 2 and wave.size == 1:
        photons = photons[:, :, None]
    if photons.ndim != 3 or photons.shape[2] != wave.size:
        raise ValueError(f"scene.data.photons: expected (rows, cols, {wave.size}) to match scene.spectrum.wave, "
                         f"got {photons.shape}")
    if np.issubdtype(photons.dtype, np.integer):  # ieCompressData
        dmin, dmax, bits = (_field(data, k) for k in ("dmin", "dmax", "bitDepth"))
        if dmin is None or dmax is None:
            raise ValueError("scene.data: integer (compressed) photons need dmin and dmax (ISETCam ieCompressData)")
        # without bitDepth, the integers' own width (uint16 was ieCompressData's; a uint8 read as 16-bit was 257x dim)
        width = 8 * photons.dtype.itemsize
        bits = width if bits is None else _named_scalar(bits, "scene.data.bitDepth", p)
        if not (float(bits).is_integer() and 1 <= bits <= width):  # ieCompressData: codes 0 .. 2^bitDepth - 1
            raise ValueError(f"scene.data.bitDepth: expected an integer from 1 to {width} (the photons are "
                             f"{photons.dtype}) in {str(p)!r}, got {bits}")
        bits = int(bits)
        dmin, dmax = _named_scalar(dmin, "scene.data.dmin", p), _named_scalar(dmax, "scene.data.dmax", p)
        if not dmax >= dmin:
            raise ValueError(f"scene.data.dmin, dmax: expected dmin <= dmax in {str(p)!r}, got {dmin} and {dmax}")
        photons = dmin + photons.astype(np.float64) * (dmax - dmin) / (2**bits - 1)
    hfov = _field(scene, "wAngular")
    dist = _field(scene, "distance")
    ill = _field(_field(_field(scene, "illuminant"), "data"), "photons")
    ill_wave = _field(_field(_field(scene, "illuminant"), "spectrum"), "wave")
    ill_t = None
    if ill is not None and np.asarray(ill).size == 0:  # MATLAB's [] (ISETCam: no illuminant), not an error
        ill = None
    if ill is not None and np.issubdtype(np.asarray(ill).dtype, np.integer):
        # old files keep the illuminant compressed too (ISETCam illuminantGet 'photons': a uint32 array decoded by
        # ieUncompressData with data.min / data.max and 32 bits); its codes were read as photons, 1e6x too dim
        ill_data = _field(_field(scene, "illuminant"), "data")
        ill = np.asarray(ill)
        if ill.dtype != np.uint32:
            raise ValueError(f"scene.illuminant.data.photons: expected numbers, or uint32 codes (ISETCam's compressed "
                             f"form), in {str(p)!r}, got {ill.dtype}")
        lo, hi = _field(ill_data, "min"), _field(ill_data, "max")
        if lo is None or hi is None:
            raise ValueError("scene.illuminant.data: uint32 (compressed) photons need min and max (ISETCam "
                             "illuminantGet / ieUncompressData)")
        lo = _named_scalar(lo, "scene.illuminant.data.min", p)
        hi = _named_scalar(hi, "scene.illuminant.data.max", p)
        if not hi >= lo:
            raise ValueError(f"scene.illuminant.data.min, max: expected min <= max in {str(p)!r}, got {lo} and {hi}")
        ill = lo + ill.astype(np.float64) * (hi - lo) / (2**32 - 1)
    if ill is not None:
        try:
            ill = np.asarray(ill, dtype=float)
        except (TypeError, ValueError) as err:
            raise ValueError(f"scene.illuminant.data.photons: expected numbers in {str(p)!r} ({err})") from err
        if ill_wave is not None and np.asarray(ill_wave).size:  # (one on 400-500 nm was attached to a 500-600 nm
            # scene as it was)
            iw = np.asarray(ill_wave, dtype=float).reshape(-1)
            # the same grid to 0.05 nm (a single-precision or 0.01 nm-rounded copy is the same grid; a shifted one not)
            if iw.shape != wave.shape or not np.allclose(iw, wave, rtol=0, atol=0.05):
                off = float(np.abs(iw - wave).max()) if iw.shape == wave.shape else None
                raise ValueError(f"scene.illuminant.spectrum.wave: expected the scene's wavelengths "
                                 f"({wave.min():g}-{wave.max():g} nm, {wave.size}) in {str(p)!r}, got "
                                 f"{iw.min():g}-{iw.max():g} nm ({iw.size})"
                                 + ("" if off is None else f", up to {off:.3g} nm off"))
        if not np.isfinite(ill).all() or (ill < 0).any():  # (a spatially varying one of -5 was kept as metadata)
            raise ValueError(f"scene.illuminant.data.photons: expected finite non-negative photons in {str(p)!r}, got "
                             f"values from {np.nanmin(ill):.6g} to {np.nanmax(ill):.6g}")
        if ill.size == wave.size:
            ill_t = torch.as_tensor(ill.reshape(-1), dtype=dtype)
        elif ill.shape != photons.shape:  # spatially varying illuminants (rows, cols, wave): metadata only
            raise ValueError(f"scene.illuminant.data.photons: expected {wave.size} values (one per wavelength) or "
                             f"the photons' shape {photons.shape} in {str(p)!r}, got shape {ill.shape}")
    name = _field(scene, "name")
    name = name if isinstance(name, str) and name else p.stem  # (MATLAB's '' is an empty array in a v5 file)
    if photons.dtype.kind == "f" and np.isfinite(photons).all() and dtype.is_floating_point and photons.size:
        big = float(np.abs(photons).max())
        if big > torch.finfo(dtype).max:  # (finite values were refused as 'NaN/Inf entries')
            raise ValueError(f"dtype: {str(p)!r} holds photons up to {big:.6g}, beyond {dtype}'s range (max "
                             f"{torch.finfo(dtype).max:g}); read it with dtype=torch.float64")
    cube = torch.as_tensor(np.ascontiguousarray(np.transpose(photons, (2, 0, 1))), dtype=dtype)[None]
    # ISETCam's defaults where the file has no wAngular / distance, recorded as read_scene_exr records them
    meta = {"source": str(p), "format": "isetcam",
            "defaulted": [k for k, v in (("hfov_deg", hfov), ("distance_m", dist)) if v is None]}
    if ill is not None and ill_t is None:
        meta["illuminant_photons_map"] = torch.as_tensor(np.transpose(ill, (2, 0, 1)).copy(), dtype=dtype)
    try:
        return Scene(cube, torch.as_tensor(wave, dtype=dtype), name=name, metadata=meta,
                     hfov_deg=10.0 if hfov is None else _named_scalar(hfov, "scene.wAngular", p),
                     distance_m=1.2 if dist is None else _named_scalar(dist, "scene.distance", p),
                     illuminant_photons=ill_t)
    except ValueError as err:  # a value the scene refuses (a descending wave): say which file
        raise ValueError(f"path: {str(p)!r}: {err}") from err


def _named_scalar(x, name: str, path: Path) -> float:
    """A MATLAB scalar field as a float, or a ValueError naming the field and the file (an empty array, a string)."""
    try:
        a = np.asarray(_unwrap(x), dtype=float).reshape(-1)
    except (TypeError, ValueError):
        a = np.empty(0)
    if a.size != 1:
        raise ValueError(f"{name}: expected a number in {str(path)!r}, got {_unwrap(x)!r}")
    return float(a[0])


# --- parity cases (isetcam-parity/FORMAT.md) ------------------------------------------------------------------

#: FORMAT.md section 3, "Required keys (present in every case)", in the table's order. ``sensor_dv`` is required too
#: when ``sensor_quantization`` is not ``'analog'`` (the table: "Only in quantized cases").
REQUIRED = ("scene_photons", "wavelengths_nm", "scene_hfov_deg", "scene_distance_m", "scene_mean_luminance_cdm2",
            "optics_f_number", "optics_focal_length_m", "optics_offaxis", "optics_transmittance", "oi_photons",
            "oi_hfov_deg", "oi_sample_spacing_m", "oi_pad_rows", "oi_pad_cols", "oi_mean_illuminance_lux",
            "sensor_rows", "sensor_cols", "sensor_pixel_size_m", "sensor_fill_factor",
            "sensor_conversion_gain_v_per_e", "sensor_voltage_swing_v", "sensor_exposure_s", "sensor_cfa",
            "sensor_filter_names", "sensor_spectral_qe", "sensor_analog_gain", "sensor_analog_offset",
            "sensor_quantization", "sensor_volts", "meta")
#: the keys :func:`case_scene_oi` reads: the scene and the optics
SCENE_KEYS = ("scene_photons", "wavelengths_nm", "scene_hfov_deg", "scene_distance_m", "optics_f_number",
              "optics_focal_length_m", "optics_offaxis", "optics_transmittance")
#: the noise parameters FORMAT.md section 3 puts in every case ("Noise keys"); the noise statistics need them
NOISE_KEYS = ("sensor_read_noise_v", "sensor_dark_voltage_v_per_s", "sensor_dsnu_sigma_v", "sensor_prnu_sigma_percent")
#: ``optics_offaxis`` values and the ``compute_oi`` mode each means: FORMAT.md's ``'cos4th'`` (every case), and
#: ``'skip'`` / ``'none'`` for no off-axis fall-off
OFFAXIS = {"cos4th": "cos4th", "skip": "skip", "none": "skip"}
_SCALARS = ("scene_hfov_deg", "scene_distance_m", "scene_mean_luminance_cdm2", "optics_f_number",
            "optics_focal_length_m", "oi_hfov_deg", "oi_sample_spacing_m", "oi_mean_illuminance_lux",
            "sensor_pixel_size_m", "sensor_fill_factor", "sensor_conversion_gain_v_per_e", "sensor_voltage_swing_v",
            "sensor_exposure_s", "sensor_analog_gain", "sensor_analog_offset")
_COUNTS = ("oi_pad_rows", "oi_pad_cols", "sensor_rows", "sensor_cols")
_FORMAT_STRING = "FORMAT.md section 2: a 0-d '<U' array; a size-1 array, bytes or a 1-d char array are read too"


def _missing(key: str) -> ValueError:
    return ValueError(f"missing required key {key!r} (FORMAT.md section 3)")


def _get(case, key: str):
    if key not in case:
        raise _missing(key)
    return case[key]


def _numeric(case, key: str) -> np.ndarray:
    a = np.asarray(_get(case, key))
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{key}: expected numbers, got a {a.dtype} array of shape {a.shape}")
    return a


def _scalar(case, key: str) -> float:
    """``case[key]`` as a float: a number of any shape of size 1 (0-d as FORMAT.md 2 writes it, or the ``[1]`` /
    ``[1, 1]`` of a MATLAB export), finite. Other sizes are an error naming the key and the shape."""
    a = _numeric(case, key)
    if a.size != 1:
        raise ValueError(f"{key}: expected a scalar (an array of size 1), got shape {a.shape}")
    x = float(a.reshape(-1)[0])
    if not math.isfinite(x):
        raise ValueError(f"{key}: expected a finite number, got {x}")
    return x


def _positive(case, key: str, maximum: float | None = None) -> float:
    """``case[key]`` (:func:`_scalar`) above 0 (and at most ``maximum``), or an error naming the key: the library's
    own check named its argument (``analog_gain: expected positive values``), not the case's key."""
    x = _scalar(case, key)
    if not (x > 0 and (maximum is None or x <= maximum)):
        bound = "a positive number" if maximum is None else f"a number in (0, {maximum:g}]"
        raise ValueError(f"{key}: expected {bound}, got {x!r}")
    return x


def _integer(case, key: str) -> int:
    """``case[key]`` as an int (:func:`_scalar`, and integral: 198.5 is an error, not truncated)."""
    x = _scalar(case, key)
    if not x.is_integer():
        raise ValueError(f"{key}: expected an integer, got {x!r}")
    return int(x)


def _decode(b: bytes, key: str) -> str:
    try:
        return bytes(b).decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{key}: expected UTF-8 text, got bytes {bytes(b)[:40]!r}") from err


def _string(value, key: str) -> str:
    """A string value, stripped: ``str`` or ``bytes`` (decoded), a size-1 array of one (a 0-d ``'<U'`` array, or a
    MATLAB cell export's ``[1]`` / ``[1, 1]``), or a 1-d array of single characters (a MATLAB char array:
    ``['1', '0']`` is ``'10'``). Anything else is an error naming ``key``."""
    if isinstance(value, (bytes, np.bytes_)):
        return _decode(value, key).strip()
    if isinstance(value, str):
        return value.strip()
    a = np.asarray(value)
    if a.dtype.kind in "US":
        if a.size == 1:
            return _string(a.reshape(-1)[0].item(), key)
        if a.size == 0:
            return ""
        if sum(n > 1 for n in a.shape) == 1:
            chars = [_decode(c, key) if isinstance(c, bytes) else c for c in a.reshape(-1).tolist()]
            if all(len(c) <= 1 for c in chars):
                return "".join(chars).strip()
    raise ValueError(f"{key}: expected a string ({_FORMAT_STRING}), got a {a.dtype} array of shape {a.shape}")


def _case_string(case, key: str) -> str:
    return _string(_get(case, key), key)


def _strings(case, key: str) -> list[str]:
    """A list of strings ``[C]`` (also ``[1, C]`` / ``[C, 1]``, or one 0-d string), each read by :func:`_string`."""
    a = np.asarray(_get(case, key))
    if sum(n > 1 for n in a.shape) > 1:
        raise ValueError(f"{key}: expected a list of strings [C] (or [1, C] / [C, 1]), got shape {a.shape}")
    names = [_string(x, f"{key}[{i}]") for i, x in enumerate(a.reshape(-1))]
    if not names or not all(names):
        raise ValueError(f"{key}: expected one non-empty name per filter, got {names}")
    return names


def _vector(case, key: str, n: int, what: str = "one per wavelength in wavelengths_nm") -> np.ndarray:
    """A numeric vector of ``n`` finite values, ``[n]`` (also ``[1, n]`` / ``[n, 1]``), as float64 ``[n]``."""
    a = _numeric(case, key)
    if a.size != n or sum(d > 1 for d in a.shape) > 1:
        raise ValueError(f"{key}: expected {n} values ({what}), got shape {a.shape}")
    v = a.astype(np.float64).reshape(-1)
    if not np.isfinite(v).all():
        raise ValueError(f"{key}: expected finite values, got {int((~np.isfinite(v)).sum())} NaN/Inf")
    return v


def _wavelengths(case) -> np.ndarray:
    """``wavelengths_nm`` ``[L]`` (float64): finite, positive, strictly increasing, in nm."""
    from .._checks import check_wavelengths

    a = _numeric(case, "wavelengths_nm")
    if a.size == 0 or sum(d > 1 for d in a.shape) > 1:
        raise ValueError(f"wavelengths_nm: expected a vector [L] of wavelengths (nm), got shape {a.shape}")
    w = a.astype(np.float64).reshape(-1)
    check_wavelengths(torch.as_tensor(w))
    check_nanometres(w, "wavelengths_nm")
    return w


def _image(case, key: str, layout: str, ndim: int) -> np.ndarray:
    a = _numeric(case, key)
    if a.ndim != ndim:
        raise ValueError(f"{key}: expected a {layout} array, got shape {a.shape}")
    return a


def _photons(case, key: str, layout: str, n_l: int) -> np.ndarray:
    """A spectral cube ``[L, ...]`` with L = ``n_l``, finite and non-negative."""
    a = _image(case, key, layout, 3)
    if a.shape[0] != n_l:
        raise ValueError(f"{key}: expected {layout} with L = {n_l} (wavelengths_nm), got shape {a.shape}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ValueError(f"{key}: expected finite values, got {int((~np.isfinite(a)).sum())} NaN/Inf")
    if (a < 0).any():
        raise ValueError(f"{key}: expected non-negative photons, got a minimum of {float(a.min()):.6g}")
    return a


def case_spectral_qe(case) -> np.ndarray:
    """``sensor_spectral_qe`` as float64 ``[C, L]``: C = the filters of ``sensor_filter_names``, L = the wavelengths.

    FORMAT.md sections 2-3 fix the layout: ``[C,L]``, row k = filter ``sensor_filter_names[k]``. A transposed
    ``[L, C]`` array (MATLAB's ``sensorGet(sensor, 'spectral qe')`` order) is refused, not guessed: the format has one
    orientation, and for C = L the two could not be told apart. ``[L]`` is read as ``[1, L]`` for one filter.
    """
    c = len(_strings(case, "sensor_filter_names"))
    n_l = _wavelengths(case).size
    a = _numeric(case, "sensor_spectral_qe")
    if a.shape != (c, n_l) and not (c == 1 and a.shape == (n_l,)):
        hint = (" (an [L, C] array, transposed: FORMAT.md sections 2-3 store row k = filter k)"
                if a.shape == (n_l, c) else "")
        raise ValueError(f"sensor_spectral_qe: expected shape (C, L) = ({c}, {n_l}) ({c} filters in "
                         f"sensor_filter_names, {n_l} wavelengths in wavelengths_nm), got {a.shape}{hint}")
    q = a.astype(np.float64).reshape(c, n_l)
    if not np.isfinite(q).all() or (q < 0).any():
        raise ValueError("sensor_spectral_qe: expected finite, non-negative values")
    return q


def case_offaxis(case) -> str:
    """``optics_offaxis`` as :func:`~isettorch.optics.isetcam.compute_oi`'s ``offaxis``: 'cos4th' or 'skip'."""
    v = _case_string(case, "optics_offaxis")
    if v.lower() not in OFFAXIS:
        raise ValueError(f"optics_offaxis: expected one of {', '.join(map(repr, OFFAXIS))} (FORMAT.md section 3: "
                         f"'cos4th' in every case), got {v!r}")
    return OFFAXIS[v.lower()]


def case_regrid_kernel(case) -> np.ndarray | None:
    """``sensor_regrid_kernel`` as a float64 ``[k, k]`` array (k >= 1; a 0-d value is ``[[x]]``), None if absent."""
    if "sensor_regrid_kernel" not in case:
        return None
    a = _numeric(case, "sensor_regrid_kernel")
    k = np.atleast_2d(a).astype(np.float64)
    if a.ndim > 2 or k.shape[0] != k.shape[1] or k.size == 0 or not np.isfinite(k).all():
        raise ValueError(f"sensor_regrid_kernel: expected a finite square [k, k] kernel with k >= 1 (FORMAT.md 4.6 "
                         f"step 2), got shape {a.shape}")
    return k


def check_parity_case(case) -> None:
    """Check a case's keys, types and shapes against FORMAT.md sections 2-3 (what :func:`read_parity_case` does).

    Every required key (:data:`REQUIRED`) must be there; scalars are numbers of size 1, counts integers, strings
    strings (:func:`_string`); every per-wavelength array has the length of ``wavelengths_nm``; ``oi_photons`` is the
    scene padded by ``oi_pad_rows`` / ``oi_pad_cols`` per side; the sensor arrays are ``[rows, cols]``; ``sensor_dv``
    is there exactly when the sensor is quantized. Optional keys are checked only when present.

    Raises:
        ValueError: the first problem, naming the key, what was expected and what the case holds.
    """
    for key in REQUIRED:
        if key not in case:
            raise _missing(key)
    n_l = _wavelengths(case).size
    for key in _SCALARS:
        _scalar(case, key)
    counts = {key: _integer(case, key) for key in _COUNTS}
    for key, n in counts.items():
        if n < (0 if key.startswith("oi_pad") else 1):
            raise ValueError(f"{key}: expected {'a non-negative' if key.startswith('oi_pad') else 'a positive'} "
                             f"count, got {n}")
    _case_string(case, "meta")
    case_offaxis(case)
    _vector(case, "optics_transmittance", n_l)
    if "vlambda" in case:
        _vector(case, "vlambda", n_l)
    scene = _photons(case, "scene_photons", "[L, H, W]", n_l)
    oi = _photons(case, "oi_photons", "[L, H2, W2]", n_l)
    padded = (n_l, scene.shape[1] + 2 * counts["oi_pad_rows"], scene.shape[2] + 2 * counts["oi_pad_cols"])
    if oi.shape != padded:
        raise ValueError(f"oi_photons: expected shape {padded} ([L, H + 2 oi_pad_rows, W + 2 oi_pad_cols], FORMAT.md "
                         f"section 3), got {oi.shape}")
    channels = case_spectral_qe(case).shape[0]
    case_cfa(case)
    bits = case_adc_bits(case)
    size = (counts["sensor_rows"], counts["sensor_cols"])
    for key in ("sensor_volts", "sensor_dv", "sensor_signal_current_a"):
        if key not in case:
            continue
        a = _image(case, key, "[rows, cols]", 2)
        if a.shape != size:
            raise ValueError(f"{key}: expected shape {size} (sensor_rows, sensor_cols), got {np.shape(case[key])}")
        if a.dtype.kind == "f" and not np.isfinite(a).all():  # (a NaN reference scored as a FAIL, exit 1)
            raise ValueError(f"{key}: expected finite values, got {int((~np.isfinite(a)).sum())} NaN/Inf")
    if bits is not None and "sensor_dv" not in case:
        raise ValueError(f"missing required key 'sensor_dv' (FORMAT.md section 3: every quantized case holds it; "
                         f"sensor_quantization is {_case_string(case, 'sensor_quantization')!r})")
    if bits is None and "sensor_dv" in case:
        raise ValueError("sensor_dv: the case is analog (sensor_quantization 'analog'), but FORMAT.md section 3 has "
                         "sensor_dv only in quantized cases")
    case_regrid_kernel(case)
    if "noise_resid_std_v" in case:  # the noise statistics (parity's noise_stats stage) read these
        for key in NOISE_KEYS:
            _scalar(case, key)
        if (_vector(case, "noise_resid_std_v", channels, "one per filter") <= 0).any():
            raise ValueError(f"noise_resid_std_v: expected positive standard deviations, got "
                             f"{np.asarray(case['noise_resid_std_v']).tolist()}")
        if "noise_resid_mean_v" in case:
            _vector(case, "noise_resid_mean_v", channels, "one per filter")
        if "noise_nruns" in case and _integer(case, "noise_nruns") < 2:
            raise ValueError(f"noise_nruns: expected at least 2 runs, got {_integer(case, 'noise_nruns')}")


def read_parity_case(path, *, check: bool = True) -> dict:
    """A parity case as a dict of NumPy values (``np.load(..., allow_pickle=False)``: no object arrays).

    Args:
        path: the ``.npz`` file.
        check: check the case against FORMAT.md sections 2-3 (:func:`check_parity_case`).
    Raises:
        ValueError: the file is missing, not an ``.npz`` (zip) archive, holds something else than arrays, or (with
            ``check``) the case does not follow FORMAT.md.
    """
    import zipfile

    p = Path(path)
    if p.is_dir():
        raise ValueError(f"path: {str(p)!r} is a folder, expected a parity case .npz file")
    if not p.is_file():
        raise ValueError(f"path: no such parity case {str(p)!r}")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"path: {str(p)!r} is not an .npz (zip) archive")
    try:
        d = np.load(p, allow_pickle=False)
        if not isinstance(d, np.lib.npyio.NpzFile):
            raise ValueError(f"expected an .npz archive of arrays, np.load read a {type(d).__name__}")
        with d:
            case = {}
            for k in d.files:
                try:
                    case[k] = d[k]
                except ValueError as err:
                    if "allow_pickle" in str(err):
                        raise ValueError(f"member {k!r} holds an object array (pickled data), which FORMAT.md "
                                         f"section 2 excludes") from err
                    raise
                if not isinstance(case[k], np.ndarray):
                    raise ValueError(f"member {k!r} is not a .npy array")
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise ValueError(f"path: {str(p)!r} is not a readable parity case (.npz): {err}") from err
    if check:
        check_parity_case(case)
    return case


def write_parity_case(path, case: dict) -> None:
    """Write a parity case (``np.savez``); values must be NumPy-convertible without object arrays (FORMAT.md 2)."""
    arrays = {}
    for k, v in case.items():
        a = np.asarray(v.detach().cpu().numpy() if isinstance(v, torch.Tensor) else v)
        if a.dtype == object:
            raise ValueError(f"case[{k!r}]: expected a numeric or string array, got an object array")
        arrays[k] = a
    def save(tmp):
        with open(tmp, "wb") as f:  # (np.savez appends .npz to a name without it)
            np.savez(f, **arrays)

    write_atomic(path, save)  # under a temporary name, moved into place when whole (a failure leaves none)


def case_cfa(case: dict):
    """The case's CFA: the pattern (``sensor_cfa_pattern``, 1-based) over the filter order of
    ``sensor_filter_names``, letters from ``sensor_filter_letters`` (or the names' first letters); the full
    filter names become the channel names when the letters are not distinct known CFA letters."""
    from ..sensor.cfa import KNOWN_LETTERS

    names = _strings(case, "sensor_filter_names")
    if "sensor_filter_letters" in case:
        letters = list(_case_string(case, "sensor_filter_letters").upper())
    else:
        letters = [n[:1].upper() for n in names]
    if len(letters) != len(names) or len(set(letters)) != len(letters) or \
            any(x not in KNOWN_LETTERS for x in letters):
        letters = names  # fall back to the full filter names as channel names
    s = _case_string(case, "sensor_cfa") if "sensor_cfa" in case else ""
    if "sensor_cfa_pattern" in case:
        raw = _numeric(case, "sensor_cfa_pattern")
        pat = np.atleast_2d(raw)
        if raw.ndim > 2 or pat.size == 0 or not np.isfinite(pat).all() or (pat != np.round(pat)).any() or \
                pat.min() < 1 or pat.max() > len(names):
            raise ValueError(f"sensor_cfa_pattern: expected a [pr, pc] array of 1-based indices into "
                             f"{len(names)} filters, got {raw.tolist()}")
        cell = [[letters[int(i) - 1] for i in row] for row in pat]
        cfa = _case_cfa(cell, letters)
        if s and all(len(x) == 1 for x in letters) and cfa.pattern != s.upper():
            raise ValueError(f"sensor_cfa: {s!r} disagrees with sensor_cfa_pattern ({cfa.pattern!r})")
        return cfa
    if not s:
        raise _missing("sensor_cfa")
    side = math.isqrt(len(s))
    if side * side != len(s):  # (CFA's message named its own 'cell' argument and an 'RG/GB' syntax a case cannot hold)
        raise ValueError(f"sensor_cfa: {s!r} is not a square cell ({len(s)} letters) and the case has no "
                         f"sensor_cfa_pattern to give its shape (FORMAT.md section 2)")
    return _case_cfa(s, letters)


def _case_cfa(cell, letters):
    """The case's CFA, a disagreement between its cell and its filters named by the case's keys (the library's
    message named its own ``channel_names``)."""
    from ..sensor.cfa import CFA

    try:
        return CFA(cell, channel_names=letters)
    except ValueError as err:
        raise ValueError(f"sensor_cfa / sensor_cfa_pattern, sensor_filter_names / sensor_filter_letters: the cell and "
                         f"the filters disagree ({err})") from err


def case_adc_bits(case: dict) -> int | None:
    """ADC bits from ``sensor_quantization`` (``'analog'``, or the bit count: ``'10'``, ``'10 bit'``); None for an
    analog sensor. The required ``sensor_quantization`` decides; the optional ``sensor_quantization_bits`` is not
    read (``isettorch parity`` notes when it disagrees)."""
    import re

    q = _case_string(case, "sensor_quantization")
    m = re.fullmatch(r"(\d+)(?:\s*-?\s*bits?)?", q.lower())
    if q.lower() == "analog":
        bits = None
    elif m and 1 <= int(m.group(1)) <= 32:
        bits = int(m.group(1))
    else:
        raise ValueError(f"sensor_quantization: expected 'analog' or a bit count from 1 to 32 such as '10' "
                         f"(FORMAT.md section 3), got {q!r}")
    return bits


def case_sensor(case: dict, preblur_size: int | None = None):
    """A :class:`~isettorch.sensor.Sensor` with the case's parameters and ISETCam's conventions
    (``ISETCAM_CONVENTIONS``: pre-blur + point sampling, gain divides, ADC without clamp), noise off, volts out.

    ISETCam integrates over wavelength with a plain rectangle rule, the bin width ``wave[1] - wave[0]`` for every
    band (FORMAT.md 4.1): ``ISETCAM_CONVENTIONS``' ``spectral_rule='isetcam'``. The case's OI has the case's
    wavelengths, so the QE is not resampled.
    """
    from ..sensor import ISETCAM_CONVENTIONS, Sensor, SpectralQE

    cfa = case_cfa(case)
    wave = torch.as_tensor(_wavelengths(case), dtype=torch.float64)
    qe = torch.as_tensor(case_spectral_qe(case), dtype=torch.float64)
    if qe.shape[0] != cfa.num_channels:
        raise ValueError(f"sensor_spectral_qe: expected {cfa.num_channels} rows (the CFA's filters), got {qe.shape[0]}")
    name = _case_string(case, "case_name") if "case_name" in case else ""
    return Sensor(
        rows=_integer(case, "sensor_rows"), cols=_integer(case, "sensor_cols"),
        pixel_size_m=_positive(case, "sensor_pixel_size_m"), fill_factor=_positive(case, "sensor_fill_factor", 1.0),
        cfa=cfa, spectral_qe=SpectralQE(qe, wave, cfa.channel_names),
        conversion_gain_v_per_e=_positive(case, "sensor_conversion_gain_v_per_e"),
        voltage_swing_v=_positive(case, "sensor_voltage_swing_v"), exposure_s=_positive(case, "sensor_exposure_s"),
        analog_gain=_positive(case, "sensor_analog_gain"), analog_offset_v=_scalar(case, "sensor_analog_offset"),
        adc_bits=case_adc_bits(case), shot_noise="off", preblur_size=preblur_size, output_units="volts", name=name,
        **ISETCAM_CONVENTIONS,
    )


def case_optical_image(case: dict):
    """The case's own optical image (``oi_photons``) as an :class:`~isettorch.optics.OpticalImage` (float64)."""
    from ..optics.optical_image import OpticalImage

    wave = _wavelengths(case)
    photons = _photons(case, "oi_photons", "[L, H2, W2]", wave.size)
    return OpticalImage(torch.as_tensor(photons, dtype=torch.float64)[None], torch.as_tensor(wave),
                        sample_spacing_m=_scalar(case, "oi_sample_spacing_m"),
                        pad_rows=_integer(case, "oi_pad_rows"), pad_cols=_integer(case, "oi_pad_cols"),
                        validate=False)


def case_scene_oi(case: dict, **kwargs):
    """Our ISETCam-compatible OI of the case's scene and optics (:func:`isettorch.optics.isetcam.compute_oi`,
    float64). ``kwargs`` go to ``compute_oi`` (e.g. ``return_details=True``).

    Raises:
        ValueError: the case lacks one of :data:`SCENE_KEYS`, or one is malformed.
    """
    from ..optics.isetcam import compute_oi

    for key in SCENE_KEYS:
        _get(case, key)
    wave = _wavelengths(case)
    scene = _photons(case, "scene_photons", "[L, H, W]", wave.size)
    return compute_oi(torch.as_tensor(scene, dtype=torch.float64), torch.as_tensor(wave),
                      _scalar(case, "scene_hfov_deg"), _scalar(case, "scene_distance_m"),
                      _positive(case, "optics_f_number"), _positive(case, "optics_focal_length_m"),
                      torch.as_tensor(_vector(case, "optics_transmittance", wave.size)),
                      offaxis=case_offaxis(case), **kwargs)
