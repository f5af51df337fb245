"""Camera raw files: DNG and vendor raws read through rawpy / LibRaw (optional extra ``raw``), and a minimal DNG
writer (tifffile) for mosaics simulated by isettorch.

``read_raw`` returns the unprocessed mosaic in DN (no demosaic, no black subtraction, no scaling; a DNG's window,
CFA and black levels from its own tags) with its CFA, black and white levels, so a folder of raws feeds
``isettorch calibrate`` like 16-bit PNGs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .._checks import is_integer

__all__ = ["RawFrame", "black_level_map", "read_raw", "write_dng"]


@dataclasses.dataclass
class RawFrame:
    """A raw mosaic in DN ``(H, W)`` float64 with its CFA (row-major letters of its repeating cell, ``'RGGB'`` or a
    6 x 6 X-Trans string; rows separated by ``'/'`` where the cell is not square; None for monochrome), per-channel
    black levels in the order of the CFA letters, and the white level. ``black_level_delta_dn`` is None, or an
    ``(H, W)`` map of the black level's departure from its per-channel value where a DNG's black level varies
    beyond the CFA cell (BlackLevelDeltaH / BlackLevelDeltaV, or a BlackLevelRepeatDim the cell does not hold): the
    black level of pixel ``(y, x)`` is its channel's ``black_level_dn`` plus ``black_level_delta_dn[y, x]``."""

    data: np.ndarray
    cfa: str | None
    black_level_dn: list[float]
    white_level_dn: float | None
    black_level_delta_dn: np.ndarray | None = None
    #: how the mosaic is displayed: the TIFF / EXIF Orientation (1 as stored, 6 rotated 90 degrees clockwise, ...;
    #: a DNG's IFD 0 tag, LibRaw's flip for other raws), not applied to ``data`` (its CFA phase would change)
    orientation: int = 1


def _tile(cell: np.ndarray, h: int, w: int) -> np.ndarray:
    """A repeating ``cell`` ``[p, q]`` over ``h x w`` pixels, from its top-left corner."""
    p, q = cell.shape
    return np.tile(cell, (-(-h // p), -(-w // q)))[:h, :w]


def black_level_map(cfa: str | None, black_level_dn, black_level_delta_dn, shape: tuple[int, int]) -> np.ndarray:
    """The black level of every pixel ``(H, W)`` of a raw frame: its per-channel ``black_level_dn`` (in the order of
    the CFA cell's letters, :class:`RawFrame`) over the cell, plus ``black_level_delta_dn`` where given."""
    from ..sensor.cfa import CFA

    cell_shape = CFA(cfa).shape if cfa is not None else (1, 1)
    level = _tile(np.asarray(black_level_dn, dtype=np.float64).reshape(cell_shape), *shape)
    return level if black_level_delta_dn is None else level + black_level_delta_dn


def read_raw(path: str | Path) -> RawFrame:
    """Read a DNG or camera raw with rawpy (LibRaw). Raises ImportError naming the extra when rawpy is missing and
    ValueError naming the file when LibRaw cannot read it.

    A DNG's pixels are LibRaw's (decompressed, linearised) but its window, CFA and black levels are read from its
    raw IFD's tags (Adobe DNG Specification 1.4.0.0, chapter 4: ActiveArea, CFARepeatPatternDim, CFAPattern,
    CFAPlaneColor, BlackLevelRepeatDim, BlackLevel, BlackLevelDeltaH/V, all relative to the ActiveArea's top-left
    corner), where LibRaw 0.22 is wrong without a word: it rounds an odd ActiveArea margin up (a row or column
    lost), shifts an X-Trans pattern by the margins (the wrong phase unless they are multiples of 6), reads a 4 x 4
    (Quad-Bayer) pattern as its 2 x 2 corner, names every 4-colour CFA GMCY, floors a fractional black level and
    averages per-row and per-column deltas into one value. The whole ActiveArea is returned (DefaultCrop is not
    applied) in the sensor's orientation (the Orientation tag is not applied: data and CFA stay consistent; it is
    ``orientation``, for the processed image).
    Other raws are LibRaw's ``raw_image_visible`` with its pattern and black levels."""
    try:
        import rawpy
    except ImportError as err:
        raise ImportError("read_raw: camera raws need rawpy; pip install 'isettorch[raw]'") from err
    path = Path(path)
    dng = _read_dng_tags(path) if path.suffix.lower() == ".dng" else None
    try:
        with rawpy.imread(str(path)) as r:
            full = r.raw_image if dng is not None else r.raw_image_visible
            data = np.array(full, dtype=np.float64)
            pattern = np.asarray(r.raw_pattern) if r.raw_pattern is not None else None
            desc = r.color_desc.decode("ascii", "replace")
            blacks = [float(b) for b in r.black_level_per_channel]
            white = float(r.white_level) if r.white_level else None
            flip = int(getattr(r.sizes, "flip", 0))
    except Exception as err:
        raise ValueError(f"{path}: cannot read the raw file with rawpy/LibRaw ({err})") from err
    if data.ndim != 2:  # (a LinearRaw DNG came back (H, W, 4))
        raise ValueError(f"{path}: a demosaiced raw (shape {data.shape}, e.g. a LinearRaw DNG); expected a colour "
                         f"filter array mosaic")
    if dng is not None:
        return dng.frame(path, data, white)
    cfa = None
    if pattern is not None and pattern.size > 1:
        cfa = "".join(desc[int(i)] for i in pattern.reshape(-1))
        if not set(cfa) <= set("RGB"):  # LibRaw labels every 4-colour CFA GMCY, whatever its colours
            raise ValueError(f"{path}: a {cfa} colour filter array, whose colours LibRaw does not report (it names "
                             f"every 4-colour CFA GMCY); only R, G, B mosaics are read: give the frames as .npy with "
                             f"cfa in capture.yaml")
        blacks = [blacks[int(i)] for i in pattern.reshape(-1)]
    _check_black_below_white(path, blacks, white)
    # LibRaw's flip (dcraw's: 3 rotated 180 degrees, 5 90 counter-clockwise, 6 90 clockwise) as TIFF Orientation
    return RawFrame(data=data, cfa=cfa, black_level_dn=blacks, white_level_dn=white,
                    orientation={3: 3, 5: 8, 6: 6}.get(flip, 1))


def _check_black_below_white(path: Path, blacks, white: float | None) -> None:
    if white is not None and max(blacks) >= white:  # (the DNG specification asks black < white)
        raise ValueError(f"{path}: black level {max(blacks):g} DN is not below the white level {white:g} DN")


_DNG_PLANE_LETTERS = "RGBCMYW"  # CFAPlaneColor codes 0..6 (DNG 1.4, CFAPlaneColor: red ... white)


@dataclasses.dataclass
class _DngRaw:
    """What a DNG's raw IFD says about its mosaic (tags relative to the ActiveArea's top-left corner)."""

    shape: tuple[int, int]  # the raw IFD's ImageLength, ImageWidth
    active: tuple[int, int, int, int]  # ActiveArea top, left, bottom, right
    cell: list[list[str]] | None  # CFA letters per row of the repeating cell; None: monochrome
    black: np.ndarray  # BlackLevel, (repeat rows, repeat cols)
    delta_v: np.ndarray  # BlackLevelDeltaV, one per ActiveArea row
    delta_h: np.ndarray  # BlackLevelDeltaH, one per ActiveArea column
    orientation: int = 1  # IFD 0's Orientation (DNG 1.4: it applies to the raw image)

    def frame(self, path: Path, full: np.ndarray, white: float | None) -> RawFrame:
        if full.shape != self.shape:
            raise ValueError(f"{path}: LibRaw read a {full.shape[0]} x {full.shape[1]} raw where the DNG's raw IFD is "
                             f"{self.shape[0]} x {self.shape[1]}; cannot place its ActiveArea and CFA")
        top, left, bottom, right = self.active
        data = full[top:bottom, left:right]
        h, w = data.shape
        level = _tile(self.black, h, w) + self.delta_v[:, None] + self.delta_h[None, :]  # every pixel's black
        p, q = (len(self.cell), len(self.cell[0])) if self.cell is not None else (1, 1)
        if h < p or w < q:
            raise ValueError(f"{path}: an ActiveArea of {h} x {w} pixels holds no whole {p} x {q} CFA cell")
        per_cell = np.array([[level[i::p, j::q].mean() for j in range(q)] for i in range(p)])
        delta = level - _tile(per_cell, h, w)
        blacks = [float(b) for b in per_cell.reshape(-1)]
        _check_black_below_white(path, blacks, white)
        cfa = None
        if self.cell is not None:
            cfa = ("".join(sum(self.cell, [])) if p == q else "/".join("".join(r) for r in self.cell))
        return RawFrame(data=data, cfa=cfa, black_level_dn=blacks, white_level_dn=white,
                        black_level_delta_dn=delta if np.any(delta != 0) else None, orientation=self.orientation)


def _tag_values(page, code: int):
    """A tag's ``(values, TIFF type)`` as stored, or None (converted by :func:`_as_numbers` once the file is closed)."""
    tag = page.tags.get(code)
    if tag is None:
        return None
    value = tag.value
    return (tuple(value) if isinstance(value, (tuple, list, bytes)) else (value,)), int(tag.dtype)


def _as_numbers(path: Path, code: int, stored) -> np.ndarray | None:
    """A tag's values as a finite float64 array (RATIONAL / SRATIONAL as numerator / denominator), or None; a
    non-numeric or non-finite value (an ASCII BlackLevel, a zero denominator) is a ValueError naming the tag."""
    if stored is None:
        return None
    value, kind = stored
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: DNG tag {code} holds {value[:4]!r}; expected numbers") from None
    if kind in (5, 10):  # RATIONAL, SRATIONAL: pairs
        with np.errstate(divide="ignore", invalid="ignore"):
            arr = arr[0::2] / arr[1::2]
    if not np.isfinite(arr).all():
        raise ValueError(f"{path}: DNG tag {code} holds non-finite values {arr.tolist()[:4]} (a zero denominator?)")
    return arr


#: the raw IFD tags read: ActiveArea, CFARepeatPatternDim, CFAPattern, CFAPlaneColor, BlackLevelRepeatDim,
#: BlackLevel, BlackLevelDeltaH, BlackLevelDeltaV
_DNG_TAGS = (50829, 33421, 33422, 50710, 50713, 50714, 50715, 50716)


def _read_dng_tags(path: Path) -> _DngRaw | None:
    """The raw IFD's tags of a DNG: IFD 0 or one of its SubIFDs with NewSubFileType 0 and a CFA (or a one-sample
    LinearRaw: monochrome) photometric interpretation. A file that is not a DNG (no DNGVersion tag in IFD 0) is
    refused; one that tifffile cannot parse, or without such an IFD, is left to LibRaw's own message (None). The
    tags are read while the file is open and checked after it, so a malformed tag is named, not taken for a file
    tifffile cannot parse."""
    import tifffile

    try:
        with tifffile.TiffFile(str(path)) as tif:
            first = tif.pages[0]
            is_dng = first.tags.get(50706) is not None
            turn = first.tags.get(274)
            orientation = int(turn.value) if turn is not None else 1
            info = None
            for page in [first, *(getattr(first, "pages", None) or [])]:
                kind = page.tags.get(254)
                if (0 if kind is None else int(kind.value)) == 0 and int(page.photometric) in (32803, 34892):
                    fmt = page.tags.get(339)  # SampleFormat: 3 is floating point (DNG 1.4; HDRMerge's files)
                    info = {"shape": (int(page.imagelength), int(page.imagewidth)),
                            "photometric": int(page.photometric), "samples": int(page.samplesperpixel),
                            "float": fmt is not None and 3 in np.atleast_1d(np.asarray(fmt.value)).tolist(),
                            "tags": {code: _tag_values(page, code) for code in _DNG_TAGS}}
                    break
    except Exception:  # not a TIFF, truncated: LibRaw says so
        return None
    if not is_dng:
        raise ValueError(f"{path}: not a DNG (no DNGVersion tag: a TIFF named .dng?); give the camera's DNG, or the "
                         f"frame as a 16-bit TIFF/PNG or .npy")
    if info is None:
        return None
    info["orientation"] = orientation if orientation in range(1, 9) else 1  # (0 and others: TIFF's default)
    if info["float"]:  # (LibRaw scaled the floats to 14-bit codes beside the tags' float black level: unsaid)
        raise ValueError(f"{path}: a floating-point DNG (SampleFormat 3, e.g. an HDR merge) is not supported; expected "
                         f"integer samples as the camera wrote them")
    if info["photometric"] == 34892 and info["samples"] != 1:
        raise ValueError(f"{path}: a demosaiced raw (a LinearRaw DNG of {info['samples']} samples a pixel); expected "
                         f"a colour filter array mosaic")
    return _dng_raw(path, info)


def _dng_raw(path: Path, info: dict) -> _DngRaw:
    shape = info["shape"]
    tags = {code: _as_numbers(path, code, stored) for code, stored in info["tags"].items()}
    area = tags[50829] if tags[50829] is not None else np.array([0, 0, *shape], dtype=np.float64)
    if len(area) != 4:
        raise ValueError(f"{path}: ActiveArea holds {len(area)} values; expected top, left, bottom, right")
    top, left, bottom, right = (int(v) for v in area)
    if not (0 <= top < bottom <= shape[0] and 0 <= left < right <= shape[1]):
        raise ValueError(f"{path}: ActiveArea {tuple(area)} is not inside the {shape[0]} x {shape[1]} raw")
    cell = None
    if info["photometric"] == 32803:
        dim, codes = tags[33421], tags[33422]
        planes = tags[50710] if tags[50710] is not None else np.arange(3.0)  # the planes' colours (default RGB)
        if dim is None or codes is None or len(dim) != 2 or min(dim) < 1 or len(codes) != int(dim[0]) * int(dim[1]):
            raise ValueError(f"{path}: a CFA raw without a CFARepeatPatternDim / CFAPattern pair that fits")
        # CFAPattern holds colour codes, each one of CFAPlaneColor's (TIFF/EP 4.6.4; DNG 1.4 CFAPlaneColor)
        if not set(codes) <= set(planes) or not set(planes) <= set(range(len(_DNG_PLANE_LETTERS))):
            raise ValueError(f"{path}: CFAPattern {tuple(int(c) for c in codes)} with CFAPlaneColor "
                             f"{tuple(int(c) for c in planes)}: expected colour codes 0-6 ({_DNG_PLANE_LETTERS}), "
                             f"the pattern's among the planes'")
        letters = [_DNG_PLANE_LETTERS[int(c)] for c in codes]
        q = int(dim[1])
        cell = [letters[i:i + q] for i in range(0, len(letters), q)]
    h, w = bottom - top, right - left
    repeat = (tags[50713] if tags[50713] is not None else np.array([1.0, 1.0])).astype(int)
    black = tags[50714] if tags[50714] is not None else np.zeros(1)
    if len(repeat) != 2 or min(repeat) < 1 or len(black) != repeat[0] * repeat[1]:
        raise ValueError(f"{path}: BlackLevel has {len(black)} values for a BlackLevelRepeatDim of "
                         f"{tuple(int(r) for r in repeat)} (one sample per pixel)")
    delta_v = tags[50716] if tags[50716] is not None else np.zeros(h)
    delta_h = tags[50715] if tags[50715] is not None else np.zeros(w)
    if len(delta_v) != h or len(delta_h) != w:
        raise ValueError(f"{path}: BlackLevelDeltaV / DeltaH have {len(delta_v)} / {len(delta_h)} values for an "
                         f"ActiveArea of {h} rows and {w} columns")
    return _DngRaw(shape=shape, active=(top, left, bottom, right), cell=cell, black=black.reshape(repeat),
                   delta_v=delta_v, delta_h=delta_h, orientation=info.get("orientation", 1))


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
    from .._files import write_atomic

    # under a temporary name, moved into place when whole (a failure leaves none)
    write_atomic(path, lambda tmp: tifffile.imwrite(str(tmp), arr.astype(np.uint16), photometric=32803, subfiletype=0,
                                                    extratags=tags, metadata=None))
