"""Import ISETCam scenes saved as MATLAB files (``save(fname, 'scene')`` / ``sceneSaveData``).

ISETCam's scene struct (``sceneCreate``): ``scene.data.photons`` ``(rows, cols, wave)`` in
photons/s/sr/m^2/nm, ``scene.spectrum.wave`` (nm), ``scene.wAngular`` (horizontal FOV, deg),
``scene.distance`` (m), ``scene.name``, and optionally ``scene.illuminant.data.photons`` (``[wave]`` or
``(rows, cols, wave)`` for spatially varying illuminants). Older files store compressed photons
(``ieCompressData``): integer codes with ``scene.data.dmin``, ``dmax`` and ``bitDepth``, decoded as
``dmin + code (dmax - dmin) / (2^bitDepth - 1)`` (ISETCam ``ieUncompressData``).

MATLAB v5/v7 files are read with ``scipy.io.loadmat``; v7.3 (HDF5) files with ``h5py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["read_isetcam_scene"]


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
