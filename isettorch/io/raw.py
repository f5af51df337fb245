"""Camera raw files: DNG and vendor raws read through rawpy / LibRaw (optional extra ``raw``), and a minimal DNG
writer (tifffile) for mosaics simulated by isettorch.

``read_raw`` returns the unprocessed mosaic in DN (``raw_image_visible``: no demosaic, no black subtraction, no
scaling) with its CFA, black and white levels, so a folder of raws feeds ``isettorch calibrate`` like 16-bit PNGs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .._checks import is_integer

__all__ = ["RawFrame", "read_raw", "write_dng"]


@dataclasses.dataclass
class RawFrame:
    """A raw mosaic in DN ``(H, W)`` float64 with its CFA (e.g. ``'RGGB'``; None for monochrome), per-channel black
    levels in the order of the CFA letters (row-major over the 2 x 2 cell), and the white level."""

    data: np.ndarray
    cfa: str | None
    black_level_dn: list[float]
    white_level_dn: float | None


def read_raw(path: str | Path) -> RawFrame:
    """Read a DNG or camera raw with rawpy (LibRaw). Raises ImportError naming the extra when rawpy is missing and
    ValueError naming the file when LibRaw cannot read it."""
    try:
        import rawpy
    except ImportError as err:
        raise ImportError("read_raw: camera raws need rawpy; pip install 'isettorch[raw]'") from err
    path = Path(path)
    if path.suffix.lower() == ".dng":  # LibRaw read a plain TIFF named .dng as an RGGB raw of black 0 (exit 0)
        _check_dng_version(path)
    try:
        with rawpy.imread(str(path)) as r:
            data = np.array(r.raw_image_visible, dtype=np.float64)
            pattern = np.asarray(r.raw_pattern) if r.raw_pattern is not None else None
            desc = r.color_desc.decode("ascii", "replace")
            blacks = [float(b) for b in r.black_level_per_channel]
            white = float(r.white_level) if r.white_level else None
    except Exception as err:
        raise ValueError(f"{path}: cannot read the raw file with rawpy/LibRaw ({err})") from err
    if data.ndim != 2:  # (a LinearRaw DNG came back (H, W, 4))
        raise ValueError(f"{path}: a demosaiced raw (shape {data.shape}, e.g. a LinearRaw DNG); expected a colour "
                         f"filter array mosaic")
    cfa = None
    if pattern is not None and pattern.size > 1:
        cfa = "".join(desc[int(i)] for i in pattern.reshape(-1))
        if not set(cfa) <= set("RGB"):  # LibRaw labels every 4-colour CFA GMCY, whatever its colours
            raise ValueError(f"{path}: a {cfa} colour filter array, whose colours LibRaw does not report (it names "
                             f"every 4-colour CFA GMCY); only R, G, B mosaics are read: give the frames as .npy with "
                             f"cfa in capture.yaml")
        blacks = [blacks[int(i)] for i in pattern.reshape(-1)]
    if white is not None and max(blacks) >= white:  # (the DNG specification asks black < white)
        raise ValueError(f"{path}: black level {max(blacks):g} DN is not below the white level {white:g} DN")
    return RawFrame(data=data, cfa=cfa, black_level_dn=blacks, white_level_dn=white)


def _check_dng_version(path: Path) -> None:
    """A ``.dng`` file is a DNG: its first IFD has the DNGVersion tag (Adobe DNG Specification 1.4, chapter 4);
    a file tifffile cannot parse is left to LibRaw's own message."""
    import tifffile

    try:
        with tifffile.TiffFile(str(path)) as tif:
            tags = tif.pages[0].tags
            has_version = tags.get(50706) is not None
    except Exception:  # not a TIFF, truncated: LibRaw says so below
        return
    if not has_version:
        raise ValueError(f"{path}: not a DNG (no DNGVersion tag: a TIFF named .dng?); give the camera's DNG, or the "
                         f"frame as a 16-bit TIFF/PNG or .npy")


_DNG_CFA_CODES = {"R": 0, "G": 1, "B": 2}
DNG_MIN_SIDE_PX = 22  # LibRaw 0.22 (rawpy 0.28) reads no DNG narrower or shorter than this (21 px: unsupported format)


def write_dng(path: str | Path, mosaic, *, cfa: str = "RGGB", black_level_dn: int = 0, white_level_dn: int = 65535
              ) -> None:
    """Write a Bayer mosaic ``(H, W)`` of integer DN as an uncompressed DNG 1.4 (CFA photometric interpretation,
    CFARepeatPatternDim / CFAPattern, BlackLevel, WhiteLevel, an identity ColorMatrix1; Adobe DNG Specification
    1.4.0.0, 2012, chapters 4-6), readable by LibRaw/rawpy: at least :data:`DNG_MIN_SIDE_PX` pixels a side (LibRaw
    0.22 reads no smaller raw), integer levels ``0 <= black_level_dn < white_level_dn <= 65535`` with no code above
    the white level (stricter than the DNG specification, which allows them), and a pattern with
    R, G and B (one with a colour missing reads back as a monochrome raw)."""
    import tifffile

    arr = np.asarray(mosaic)
    if arr.ndim != 2 or arr.size == 0 or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr) \
            or arr.min() < 0 \
            or arr.max() > 65535 or not np.array_equal(arr, np.round(arr)):
        raise ValueError(f"mosaic: expected a non-empty 2-D array of integers in 0..65535, got shape {arr.shape}")
    if min(arr.shape) < DNG_MIN_SIDE_PX:
        raise ValueError(f"mosaic: LibRaw reads no raw smaller than {DNG_MIN_SIDE_PX} pixels a side, got shape "
                         f"{arr.shape}")
    if not (isinstance(cfa, str) and len(cfa) == 4 and all(c in _DNG_CFA_CODES for c in cfa.upper())
            and set(cfa.upper()) == set(_DNG_CFA_CODES)):
        raise ValueError(f"cfa: expected a 2 x 2 Bayer pattern with R, G and B such as 'RGGB', got {cfa!r}")
    if not (is_integer(black_level_dn) and is_integer(white_level_dn)
            and 0 <= black_level_dn < white_level_dn <= 65535):
        raise ValueError(f"black_level_dn, white_level_dn: expected integers with 0 <= black < white <= 65535, got "
                         f"{black_level_dn!r} and {white_level_dn!r}")
    if arr.max() > white_level_dn:  # (a raw above its white level was written and read back as such)
        raise ValueError(f"mosaic: values up to {arr.max():g} DN exceed white_level_dn {white_level_dn}; a raw's "
                         f"codes are at most its white level")
    identity = (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)  # 3 x 3 SRATIONAL
    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, "isettorch", True),  # UniqueCameraModel
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, tuple(_DNG_CFA_CODES[c] for c in cfa.upper()), True),  # CFAPattern
        (50714, "H", 1, (int(black_level_dn),), True),  # BlackLevel
        (50717, "H", 1, (int(white_level_dn),), True),  # WhiteLevel
        (50721, "2i", 9, identity, True),  # ColorMatrix1
        (50778, "H", 1, (21,), True),  # CalibrationIlluminant1: D65
    ]
    tifffile.imwrite(str(path), arr.astype(np.uint16), photometric=32803, subfiletype=0, extratags=tags,
                     metadata=None)
