"""Calibration captures on disk: ``capture.yaml`` and ``dark_<ms>ms/`` / ``flat_<ms>ms/`` folders of raw frames.

Layout (``isettorch calibrate DIR``)::

    DIR/capture.yaml        bit_depth, pixel_size_m, [black_level_dn], [cfa], [photons_per_pixel: {ms: photons}]
    DIR/dark_<ms>ms/*.png   >= 2 frames per exposure (8/16-bit greyscale PNG or TIFF, .npy, or camera raws via
    DIR/flat_<ms>ms/*.tif   rawpy), values in DN, from dark to saturation

Every problem with what looks like part of the capture (missing keys, a folder with one frame, identical frames, an
unreadable file, a shape that differs, a file with a frame suffix outside the exposure folders, a folder named
``dark...``/``flat...`` that does not parse) raises a ``ValueError`` naming the file or folder. Anything else (a
``--report`` folder, ``notes.txt``, ``Thumbs.db``) is skipped and listed in :attr:`Capture.warnings`; hidden files
are skipped silently. Without ``cfa`` in capture.yaml, the CFA of camera raws (their metadata) is used, with a
warning.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .._files import write_atomic

__all__ = ["Capture", "FrameData", "read_capture", "read_frame", "read_frame_data", "write_frame", "FRAME_SUFFIXES",
           "RAW_SUFFIXES"]

FRAME_SUFFIXES = (".png", ".tif", ".tiff", ".npy")
#: how far (DN) a camera raw's own black level (the mean of its BlackLevel tags over the CFA cell) may be from its
#: camera config's: ``isettorch process`` refuses a raw beyond it (the output would carry the difference), and
#: calibration warns when a capture's raws are beyond it from the measured black level
RAW_BLACK_TOLERANCE_DN = 0.5
# Camera raws read through rawpy (optional extra ``raw``): DNG and the common vendor formats.
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".rw2", ".orf", ".pef", ".srw")
CAPTURE_KEYS = {"bit_depth", "pixel_size_m", "black_level_dn", "cfa", "photons_per_pixel"}
_FOLDER = re.compile(r"^(dark|flat)_([0-9]+(?:\.[0-9]+)?)ms$")
_GREY_MODES = ("L", "I;16", "I;16B", "I;16L", "I", "F")  # PIL greyscale modes: 8-bit, 16-bit, 32-bit int / float


@dataclasses.dataclass
class Capture:
    """A calibration capture in memory. ``dark`` / ``flat`` map exposure (ms) -> ``(N, H, W)`` DN stacks, float32 as
    :func:`read_capture` stores them up to 24 bits (every integer DN exactly, half of float64's memory: 24-megapixel
    frames, 2 per level, 20 levels of each kind take 7.7 GB), float64 above; the statistics are computed in
    float64."""

    bit_depth: int
    pixel_size_m: float
    cfa: str | None
    black_level_dn: float | None
    photons_per_pixel: dict[float, float] | None
    dark: dict[float, np.ndarray]
    flat: dict[float, np.ndarray]
    folders: dict[tuple[str, float], str]  # (kind, ms) -> folder path, for error messages
    warnings: list[str] = dataclasses.field(default_factory=list)  # what was skipped or inferred while reading
    # camera raws' own black level: the mean over the frames of their BlackLevel tags' mean over the CFA cell (DN, as
    # stored), None without raws carrying one; what ``isettorch process`` will compare with the config's
    raw_black_level_dn: float | None = None


class FrameData(NamedTuple):
    """A raw frame and what its file says about it (camera raws only; ``None`` for PNG, TIFF and ``.npy``)."""

    dn: np.ndarray  # (H, W) float64 DN
    cfa: str | None  # the mosaic's repeating cell, e.g. "RGGB" (RawFrame.cfa)
    black_level_dn: list[float] | None  # per-channel black levels (DN)
    stored_bits: int | None = None  # the file's integer sample size (8 for an 8-bit PNG); None for floats and raws
    # a DNG's black level's departure from black_level_dn per pixel (RawFrame.black_level_delta_dn), or None; ``dn``
    # is the file's codes (a capture's dark frames measure the offsets as they are)
    black_level_delta_dn: np.ndarray | None = None
    white_level_dn: float | None = None  # a camera raw's white level (DN; RawFrame.white_level_dn)
    orientation: int = 1  # a camera raw's display orientation (RawFrame.orientation; not applied to dn)


def read_frame(path: str | Path) -> np.ndarray:
    """One raw frame in DN as a 2-D float64 array: 8- or 16-bit greyscale PNG/TIFF (tifffile, or Pillow for TIFF
    compressions tifffile cannot decode without imagecodecs, e.g. LZW), ``.npy`` (no pickle) or a camera raw (DNG,
    CR2, NEF, ... via rawpy: the unprocessed mosaic, :func:`isettorch.io.raw.read_raw`)."""
    return read_frame_data(path).dn


def _pil_grey(path: Path, what: str) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        if im.mode not in _GREY_MODES:
            raise ValueError(f"expected an 8- or 16-bit greyscale {what}, got PIL mode {im.mode!r}")
        args = im.tile[0].args if im.tile else None
        raw = args if isinstance(args, str) else args[0] if isinstance(args, tuple) and args else ""
        packed = raw.split(";")[1][:1] if raw.startswith("L;") else ""
        if packed in ("1", "2", "4"):  # (Pillow widens them to 8 bits: a 4-bit code 15 read as DN 255)
            raise ValueError(f"expected 8- or 16-bit greyscale samples, got {packed}-bit ones (Pillow would widen "
                             f"them to 8 bits, changing the DN); save the frame as 8/16-bit {what} or .npy")
        return np.asarray(im)


def _read_tiff(path: Path) -> np.ndarray:
    import tifffile

    try:
        return tifffile.imread(path)
    except Exception as err:  # e.g. LZW / deflate without imagecodecs: Pillow decodes the common codecs itself
        try:
            return _pil_grey(path, "TIFF")
        except Exception as pil_err:
            raise ValueError(f"tifffile: {err}; Pillow: {pil_err}") from err


def is_exposure_folder_name(name: str) -> bool:
    """A capture subfolder :func:`read_capture` reads as an exposure folder (or refuses as a misnamed one): its name
    begins with ``dark`` or ``flat``, in any case; other subfolders are skipped with a warning."""
    return name.lower().startswith(("dark", "flat"))


def check_sample_bits(path, stored_bits: int | None, bits: int, whose: str, hint: str = "") -> None:
    """A frame stored in integer samples narrower than the ADC's ``bits`` (an 8-bit PNG of 12-bit data: a display
    export, its values shifted or clipped) is refused naming the file; ``whose`` names the bit depth's owner
    (``"camera's"``, ``"capture's"``), ``hint`` where it is set. Floats and camera raws (``stored_bits`` None)
    pass."""
    if stored_bits is not None and stored_bits < bits:
        raise ValueError(f"{path}: {stored_bits}-bit samples cannot hold the {whose} {bits}-bit DN{hint} (a display "
                         f"image, not a raw frame?); give the 16-bit PNG/TIFF or .npy frame")


def read_frame_data(path: str | Path) -> FrameData:
    """:func:`read_frame`'s frame with the CFA and per-channel black levels (DN) of a camera raw's metadata."""
    path = Path(path)
    suffix = path.suffix.lower()
    cfa, blacks, delta, white, orientation = None, None, None, None, 1
    try:
        if suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
        elif suffix in (".tif", ".tiff"):
            arr = _read_tiff(path)
        elif suffix == ".png":
            arr = _pil_grey(path, "PNG")
        elif suffix in RAW_SUFFIXES:
            from .raw import read_raw

            raw = read_raw(path)
            arr, cfa, blacks, delta = raw.data, raw.cfa, raw.black_level_dn, raw.black_level_delta_dn
            white, orientation = raw.white_level_dn, raw.orientation
        else:
            raise ValueError(f"unknown frame type {suffix!r}; expected one of {FRAME_SUFFIXES + RAW_SUFFIXES}")
    except ImportError:
        raise
    except Exception as err:  # any reader failure: name the file
        raise ValueError(f"{path}: cannot read the frame ({err})") from err
    if arr.ndim != 2 or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{path}: expected a 2-D numeric frame (H, W) in DN, got shape {arr.shape} dtype {arr.dtype}")
    if arr.size == 0:
        raise ValueError(f"{path}: expected a frame with pixels, got shape {arr.shape}")
    bits = 8 * arr.dtype.itemsize if np.issubdtype(arr.dtype, np.integer) and cfa is None else None
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all() or arr.min() < 0:
        raise ValueError(f"{path}: expected finite non-negative DN values")
    return FrameData(arr, cfa, blacks, bits, delta, white, orientation)


def write_frame(path: str | Path, frame) -> None:
    """Write a 2-D DN frame as 16-bit PNG/TIFF or ``.npy`` (by suffix); PNG/TIFF need integers in 0..65535."""
    path = Path(path)
    arr = np.asarray(frame.detach().cpu() if hasattr(frame, "detach") else frame)
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".png", ".tif", ".tiff"):
        raise ValueError(f"path: expected a .png, .tif, .tiff or .npy name, got {path.name!r}")
    if arr.ndim != 2 or arr.size == 0 or not (np.issubdtype(arr.dtype, np.number) and not np.iscomplexobj(arr)):
        raise ValueError(f"frame: expected a non-empty 2-D array of real numbers (one frame in DN), got "
                         f"{arr.dtype} of shape {arr.shape}")
    if suffix != ".npy" and (arr.min() < 0 or arr.max() > 65535 or not np.array_equal(arr, np.round(arr))):
        raise ValueError(f"frame: a 16-bit {suffix} needs integers in 0..65535, got {arr.min()}..{arr.max()}")
    def save(tmp: Path) -> None:
        if suffix == ".npy":
            with open(tmp, "wb") as f:  # (np.save adds '.npy' to a name that does not end in it: 'UP.NPY.npy')
                np.save(f, arr, allow_pickle=False)
        elif suffix == ".png":
            from PIL import Image

            Image.fromarray(arr.astype(np.uint16)).save(tmp)
        else:
            import tifffile

            tifffile.imwrite(tmp, arr.astype(np.uint16))

    write_atomic(path, save)  # under a temporary name, moved into place when whole (a failure leaves none)


def _read_yaml(path: Path) -> dict:
    from .._yaml import load_yaml

    if not path.is_file():
        raise ValueError(f"{path}: missing capture.yaml (bit_depth, pixel_size_m, optional black_level_dn, cfa, "
                         f"photons_per_pixel)")
    try:
        cfg = load_yaml(path.read_text())  # safe, YAML 1.2 floats (1e-3 is a number)
    except Exception as err:
        raise ValueError(f"{path}: cannot parse YAML ({err})") from err
    if not isinstance(cfg, dict):
        raise ValueError(f"{path}: expected a mapping of keys, got {type(cfg).__name__}")
    unknown = set(cfg) - CAPTURE_KEYS
    if unknown:  # kept strict: it catches typos (black_level instead of black_level_dn)
        raise ValueError(f"{path}: unknown key(s) {sorted(unknown)}; the accepted keys are bit_depth, pixel_size_m "
                         f"(required), black_level_dn, cfa, photons_per_pixel (optional)")
    for key in ("bit_depth", "pixel_size_m"):
        if key not in cfg:
            raise ValueError(f"{path}: missing key {key!r} (required: bit_depth, pixel_size_m)")
    bd = cfg["bit_depth"]
    if isinstance(bd, bool) or not isinstance(bd, int) or not 1 <= bd <= 32:  # (YAML true read as 1 bit)
        raise ValueError(f"{path}: bit_depth: expected an integer in 1..32, got {bd!r}")
    px = cfg["pixel_size_m"]
    if isinstance(px, bool) or not isinstance(px, (int, float)) or not (math.isfinite(px) and 0 < px < 1e-3):
        raise ValueError(f"{path}: pixel_size_m: expected a pitch in metres (e.g. 3.45e-6), got {px!r}")
    bl = cfg.get("black_level_dn")
    if bl is not None and (isinstance(bl, bool) or not isinstance(bl, (int, float)) or not 0 <= bl < 2 ** bd):
        raise ValueError(f"{path}: black_level_dn: expected a number in [0, 2^{bd}), got {bl!r}")
    cfa = cfg.get("cfa")
    if cfa is not None:
        from ..sensor.cfa import CFA

        try:
            CFA(str(cfa))
        except Exception as err:
            raise ValueError(f"{path}: cfa: {err}") from err
    ppp = cfg.get("photons_per_pixel")
    if ppp is not None:
        if not isinstance(ppp, dict):
            raise ValueError(f"{path}: photons_per_pixel: expected a mapping {{exposure_ms: photons}}, got {ppp!r}")
        try:
            ppp = {float(k): float(v) for k, v in ppp.items()}
        except (TypeError, ValueError) as err:
            raise ValueError(f"{path}: photons_per_pixel: expected numbers, got {cfg['photons_per_pixel']!r}") from err
        if any(v < 0 or not math.isfinite(v) for v in ppp.values()):
            raise ValueError(f"{path}: photons_per_pixel: expected non-negative photon counts")
    return {"bit_depth": bd, "pixel_size_m": float(px), "black_level_dn": bl, "cfa": cfa, "photons_per_pixel": ppp}


def _frame_files(folder: Path, skipped: list[Path]) -> list[Path]:
    """The frames of an exposure folder; anything without a frame suffix (notes.txt, Thumbs.db, a sub-folder) is
    appended to ``skipped``, hidden files are left out silently."""
    files = []
    for p in sorted(folder.iterdir()):
        if p.name.startswith("."):
            continue  # hidden files (.DS_Store, ...) are not frames
        if p.suffix.lower() in FRAME_SUFFIXES + RAW_SUFFIXES:
            if p.is_dir():
                raise ValueError(f"{p}: a folder with a frame's name; expected only frame files in {folder}")
            files.append(p)
        else:
            skipped.append(p)
    if len(files) < 2:
        others = [p.name for p in skipped if p.parent == folder and p.is_file()]
        hint = (f" ({len(others)} other file(s) skipped, e.g. {others[:3]}: frames are "
                f"{', '.join(FRAME_SUFFIXES + RAW_SUFFIXES)})") if others else ""
        raise ValueError(f"{folder}: expected at least 2 frames (temporal noise needs a stack), found "
                         f"{len(files)}{hint}")
    return files


def _check_copies(files: list[Path], frames: list[np.ndarray], folder: Path) -> None:
    """Two bit-identical frames in a stack are copies of one frame (a copy error): temporal noise makes independent
    frames differ. Frames with under 1 % of their pixels strictly between their minimum and maximum (a saturated or
    uniformly clipped flat) are identical legitimately and are not compared."""
    import hashlib

    seen: dict[bytes, Path] = {}
    for f, arr in zip(files, frames):
        inside = np.count_nonzero((arr > arr.min()) & (arr < arr.max()))
        if inside < 0.01 * arr.size:
            continue
        h = hashlib.blake2b(arr.tobytes(), digest_size=16).digest()
        if h in seen:
            raise ValueError(f"{folder}: frames are identical: copies of one frame? ({seen[h].name} and {f.name}; the "
                             f"temporal noise needs independent frames)")
        seen[h] = f


def _skipped_warning(root: Path, skipped: list[Path]) -> str:
    names = [str(p.relative_to(root)) + ("/" if p.is_dir() else "") for p in skipped]
    shown = names[:20] + ([f"... {len(names) - 20} more"] if len(names) > 20 else [])
    return f"skipped (not frames, exposure folders or capture.yaml): {shown}"


def read_capture(directory: str | Path, *, progress: bool = False) -> Capture:
    """Read a calibration capture folder (see the module docstring); frames become float32 DN stacks (float64 above
    24 bits: :class:`Capture`)."""
    root = Path(directory)
    if not root.is_dir():
        raise ValueError(f"{root}: not a directory")
    cfg = _read_yaml(root / "capture.yaml")
    folders: dict[tuple[str, float], Path] = {}
    skipped: list[Path] = []
    for p in sorted(root.iterdir()):
        if p.name.startswith("."):
            continue
        if p.is_dir():
            m = _FOLDER.match(p.name)
            if m:
                key = (m.group(1), float(m.group(2)))
                if key in folders:
                    raise ValueError(f"{p}: the same exposure as {folders[key]}")
                folders[key] = p
            elif is_exposure_folder_name(p.name):  # meant as an exposure folder: a naming error
                raise ValueError(f"{p}: unexpected folder name; expected dark_<exposure_ms>ms or flat_<exposure_ms>ms")
            else:  # e.g. the --report folder of an earlier run
                skipped.append(p)
        elif p.suffix.lower() in FRAME_SUFFIXES + RAW_SUFFIXES:
            raise ValueError(f"{p}: a frame outside the dark_<exposure_ms>ms / flat_<exposure_ms>ms folders")
        elif p.name != "capture.yaml":
            skipped.append(p)
    for kind in ("dark", "flat"):
        if not any(k == kind for k, _ in folders):
            raise ValueError(f"{root}: no {kind}_<exposure_ms>ms folders; a calibration needs dark and flat stacks")
    limit = 2 ** cfg["bit_depth"] - 1
    dtype = np.float32 if cfg["bit_depth"] <= 24 else np.float64  # float32 holds every integer up to 2^24 exactly
    jobs = [(k, folders[k], _frame_files(folders[k], skipped)) for k in sorted(folders)]
    total = sum(len(f) for _, _, f in jobs)
    from .._progress import progress as progress_bar

    stacks: dict[str, dict[float, np.ndarray]] = {"dark": {}, "flat": {}}
    shape = None
    first = None
    frame_cfa: dict[str | None, Path] = {}  # CFA of the files' metadata (camera raws) -> first file with it
    raw_blacks: list[float] = []  # each raw's black level tags' mean over the CFA cell
    with progress_bar(total=total, desc="reading frames", unit="frame", quiet=not progress) as bar:
        for (kind, ms), folder, files in jobs:
            frames = []
            for f in files:
                arr, cfa, blacks, stored_bits, *_ = read_frame_data(f)
                if blacks:
                    raw_blacks.append(float(np.mean(blacks)))
                check_sample_bits(f, stored_bits, cfg["bit_depth"], "capture's",  # (as isettorch process does)
                                  " (bit_depth in capture.yaml)")
                if f.suffix.lower() in RAW_SUFFIXES:
                    frame_cfa.setdefault(cfa, f)
                if shape is None:
                    shape, first = arr.shape, f
                elif arr.shape != shape:
                    raise ValueError(f"{f}: shape {arr.shape} differs from {shape} of {first}")
                if arr.max() > limit:
                    raise ValueError(f"{f}: values up to {arr.max():g} DN exceed 2^bit_depth - 1 = {limit} "
                                     f"(bit_depth {cfg['bit_depth']} in capture.yaml; are the values shifted left?)")
                frames.append(arr.astype(dtype))
                bar.update(1)
            _check_copies(files, frames, folder)
            stacks[kind][ms] = np.stack(frames)
    ppp = cfg["photons_per_pixel"]
    if ppp is not None:
        missing = sorted(ms for ms in stacks["flat"] if ms not in ppp)
        if missing:
            raise ValueError(f"{root / 'capture.yaml'}: photons_per_pixel has no value for flat exposure(s) "
                             f"{missing} ms")
    warnings = [_skipped_warning(root, skipped)] if skipped else []
    cfa = cfg["cfa"]
    if len(frame_cfa) > 1:
        (c1, f1), (c2, f2) = list(frame_cfa.items())[:2]
        if cfa is None:
            raise ValueError(f"{f2}: its CFA {c2 or 'none (mono)'} (raw metadata) differs from {c1 or 'none (mono)'} "
                             f"of {f1}; set cfa in capture.yaml if the frames are of one sensor")
        warnings.append(f"the frames' raw metadata disagree on the CFA ({c1} in {f1}, {c2} in {f2}); using "
                        f"capture.yaml's cfa {cfa}")
    elif frame_cfa:
        (c1, f1), = frame_cfa.items()
        if cfa is None and c1 is not None:
            cfa = c1
            warnings.append(f"capture.yaml has no cfa: using {c1}, the CFA in the frames' raw metadata (e.g. {f1}); "
                            f"set cfa in capture.yaml to override")
        elif cfa is not None and c1 is not None and str(c1).upper() != str(cfa).upper():
            warnings.append(f"capture.yaml's cfa {cfa} differs from {c1} in the frames' raw metadata (e.g. {f1}); "
                            f"using capture.yaml's")
    return Capture(bit_depth=cfg["bit_depth"], pixel_size_m=cfg["pixel_size_m"], cfa=cfa,
                   black_level_dn=cfg["black_level_dn"], photons_per_pixel=ppp, dark=stacks["dark"],
                   flat=stacks["flat"], folders={k: str(v) for k, v in folders.items()}, warnings=warnings,
                   raw_black_level_dn=float(np.mean(raw_blacks)) if raw_blacks else None)
