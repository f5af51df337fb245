"""Reading and writing users' RGB images: PNG (8/16-bit), TIFF (8/16-bit, float32; float16/64 read too) and
OpenEXR (float); and
:func:`read_rgb8`, the 8-bit code values of a photograph (PNG, TIFF, JPEG, BMP, WebP, GIF, PPM/PGM or TGA) as the
benchmarks and the photo lifter read them.

Value conventions (what a tensor holds, what a file holds):

- Tensors are ``[B, C, H, W]`` float, **linear** and relative (white = 1), as the ISP produces (``linear_srgb``
  targets, ``ImageProcessor`` output before encoding). ``isettorch.scene.from_rgb`` takes *encoded* values (it
  applies the display's EOTF): give it ``read_image(path, encoding="linear")``, the code values / (2^bits - 1).
- An alpha channel (the last of 2 or 4) is coverage, linear in every file format: it is never sRGB-encoded or
  decoded (PNG specification, 12.2; it was, so a linear 0.5 was stored as code 188). Tensors hold straight
  (unassociated) alpha, PNG's convention: an EXR's colour, premultiplied by alpha in the file (OpenEXR Technical
  Introduction), and a TIFF's with associated alpha (ExtraSamples 1, TIFF 6.0) are divided by it on reading (where
  it is above 0), and an EXR's multiplied by it on writing.
- Integer files (PNG, 8/16-bit TIFF) hold **sRGB-encoded** code values, the convention of every viewer:
  reading decodes them with the IEC 61966-2-1 sRGB curve (``encoding="linear"`` returns the code values
  / (2^bits - 1) unchanged instead, e.g. for data already linear such as raw mosaics); writing encodes. A PNG's
  own gAMA chunk is honoured (1.0: linear samples); one tagged with other colours than sRGB's (an ICC profile,
  cHRM) raises rather than being decoded as sRGB.
- Float files (EXR, float32 TIFF) are **linear** (scene-referred, no encoding) in both directions.
- A file tagged with other colours than sRGB's (a PNG's or TIFF's ICC profile, a PNG's cHRM, an EXR's
  chromaticities) raises with ``encoding="srgb"``; ``encoding="linear"`` returns its stored values unconverted.

Nothing is clipped silently: writing values outside [0, 1] to an integer file raises unless ``clip=True``.
A batch (B > 1) is written one file per sample through a ``{i}`` field in the path
(``"out/img_{i:03d}.png"``); without one, a batch raises instead of writing only sample 0.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from .._checks import check_bool, narrow_float
from .._files import Outputs

__all__ = ["read_image", "write_image", "read_rgb8", "rgb8_to_tensor", "photo_files", "non_srgb_profile",
           "IMAGE_SUFFIXES", "PHOTO_SUFFIXES", "UNREAD_IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = {".png": "png", ".tif": "tiff", ".tiff": "tiff", ".exr": "exr"}
_ENCODINGS = ("srgb", "linear")
_EXR_CHANNELS = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}
#: a TIFF's photometric interpretations (tag 262) whose samples are the image's values as they are; palette,
#: min-is-white, CMYK, YCbCr and CIELab files are refused by name rather than read as their stored numbers
_TIFF_PHOTOMETRIC = ("MINISBLACK", "RGB")
#: EXIF / TIFF orientation (tag 0x0112, TIFF 6.0 and EXIF 2.3) -> the stored array turned to the displayed one, as
#: Pillow's ``ImageOps.exif_transpose`` turns it
_ORIENT = {2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.swapaxes(0, 1), 6: lambda a: np.rot90(a, -1), 7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
           8: lambda a: np.rot90(a, 1)}


#: the 8-bit photographs :func:`read_rgb8` reads (the benchmark and photo-lifting folders; Pillow decodes them)
PHOTO_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".jpe", ".jfif", ".mpo", ".bmp", ".dib", ".webp", ".gif",
                  ".apng", ".ppm", ".pgm", ".pbm", ".pnm", ".tga", ".qoi")

#: image files a photo folder may hold that :func:`read_rgb8` does not read (HDR, camera raw, other codecs):
#: :func:`photo_files` refuses a folder holding one rather than leaving it out of a mean unsaid
UNREAD_IMAGE_SUFFIXES = (".heic", ".heif", ".avif", ".jxl", ".jp2", ".j2k", ".jpf", ".jpx", ".j2c", ".jpc", ".exr",
                         ".hdr", ".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf", ".psd")


def photo_files(folder) -> list[Path]:
    """The photographs of a folder, sorted by name: the files with a :data:`PHOTO_SUFFIXES` suffix (any case; the
    folder's own files, not its subfolders'), hidden ones left out (names beginning with ``.``, such as the
    ``._name.png`` AppleDouble files macOS leaves on copied folders: metadata, not images), other files (notes,
    READMEs) too. A folder holding an image in a format not read here (:data:`UNREAD_IMAGE_SUFFIXES`: HEIC, AVIF,
    camera raw, ...) raises a ``ValueError`` naming it: leaving it out would score the folder on fewer photographs
    than it holds, unsaid."""
    files = [p for p in Path(folder).iterdir() if not p.name.startswith(".") and not p.is_dir()]
    unread = sorted(p.name for p in files if p.suffix.lower() in UNREAD_IMAGE_SUFFIXES)
    if unread:
        raise ValueError(f"folder: {str(folder)!r} holds image(s) in a format not read here: {unread[:5]}"
                         f"{' ...' if len(unread) > 5 else ''}; expected {'/'.join(PHOTO_SUFFIXES)} photographs "
                         f"(convert them, e.g. to PNG, or move them out)")
    return sorted(p for p in files if p.suffix.lower() in PHOTO_SUFFIXES)


def read_rgb8(path) -> np.ndarray:
    """An 8-bit photograph as a uint8 array ``[H, W, 3]`` of its sRGB code values, unchanged (Pillow decodes it).

    The scoring convention of ``shared/data`` (8-bit code values / 255) needs 8-bit samples, so only lossless
    conversions to RGB are made: gray (``L``, ``1``) repeated in the three channels, a palette expanded, an alpha
    channel or colour key dropped when every pixel is opaque. The photograph is returned as displayed: an EXIF
    orientation (a camera's rotated JPEG) is applied (Pillow's ``ImageOps.exif_transpose``). Anything else raises a
    ``ValueError`` naming the file: transparent pixels (an alpha channel, or a gray, RGB or palette colour key, PNG's
    tRNS: compositing would be a choice), 16- or 32-bit samples (Pillow would silently keep only 8 of the bits), CMYK or
    other colour spaces, several pages or frames (a multi-page TIFF, an animation: which one is the photograph?), a
    file that is not an image.
    """
    import contextlib
    import warnings

    from PIL import Image, ImageOps

    p = Path(path)
    try:
        with contextlib.ExitStack() as stack:
            stack.enter_context(warnings.catch_warnings())
            # Pillow's warnings name no file and change nothing: a DecompressionBombWarning above 89 MP (twice that
            # raises, below), "Corrupt EXIF data" (the orientation is then not applied); they printed file:line
            # lines amid the command's output (set before the file is opened: Image.open warns)
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            warnings.filterwarnings("ignore", message="Corrupt EXIF data")
            im = stack.enter_context(Image.open(p))
            modes = [t[3][0] if isinstance(t[3], tuple) else t[3] for t in (im.tile or [])] or [""]
            rawmode = modes[0]
            deep = [m for m in modes if ";16" in str(m) or ";32" in str(m)]
            # a PPM of maxval above 255 (10 / 16-bit samples): Pillow's tile says ('RGB', maxval) and keeps 8 bits
            deep += [f"maxval {t.args[1]}" for t in (im.tile or []) if t.codec_name == "ppm" and isinstance(
                t.args, tuple) and len(t.args) > 1 and isinstance(t.args[1], int) and t.args[1] > 255]
            if im.mode in ("I", "I;16", "I;16B", "I;16L", "F") or deep:
                raise ValueError(f"{p.name}: expected 8-bit samples, got a {im.mode}/{deep[0] if deep else rawmode} "
                                 f"image (more than 8 bits per sample); convert it to 8-bit first")
            wide = _tiff_sample_type(p) if im.format == "TIFF" else None
            if wide is not None and (wide.kind == "f" or wide.itemsize > 1):  # (1-bit is bool, 4-bit uint8)
                # (a TIFF of one plane per colour, PlanarConfiguration 2, has tiles 'R', 'G', 'B' whatever their
                # depth: its 16-bit samples were decoded as bytes, and scored 15 dB where the photograph gets 32)
                raise ValueError(f"{p.name}: expected 8-bit samples, got {wide} samples (TIFF); convert it to 8-bit "
                                 f"first")
            frames = getattr(im, "n_frames", 1)
            # an MPO (a phone's JPEG with a depth map or preview appended) is the photograph in its first frame, by
            # the CIPA DC-007 format; other several-frame files do not say which frame is the photograph
            if frames > 1 and im.format != "MPO":
                raise ValueError(f"{p.name}: expected a single image, got {frames} pages or frames (a multi-page "
                                 f"{im.format} or an animation); save the photograph on its own")
            # a colour key (PNG tRNS: a gray or RGB value, or a palette's entries with alpha): its pixels are clear;
            # a key no pixel uses leaves the image opaque (a palette with an unused transparent entry was refused)
            keyed = im.mode in ("L", "RGB", "1", "P") and "transparency" in im.info
            if im.mode in ("RGBA", "LA", "PA") or keyed:
                alpha = np.asarray((im.convert("RGBA") if keyed else im).getchannel("A"))
                if alpha.size and int(alpha.min()) < 255:
                    key = (" (the palette's transparent entries)" if im.mode == "P" else
                           f" (the colour key {im.info['transparency']!r}, PNG tRNS)") if keyed else ""
                    raise ValueError(f"{p.name}: expected an opaque image, {int((alpha < 255).sum())} pixels are "
                                     f"transparent{key}")
            if im.mode not in ("RGB", "RGBA", "L", "LA", "1", "P", "PA"):
                raise ValueError(f"{p.name}: expected an 8-bit RGB, gray or palette image, got mode {im.mode!r}")
            shown = ImageOps.exif_transpose(im)  # a photograph means what it shows: its EXIF orientation applied
            a = np.asarray(shown.convert("RGB"), dtype=np.uint8)
    except OSError as err:  # not an image, truncated, unreadable
        dtype = _tiff_sample_type(p)  # a TIFF Pillow cannot open (float or 32-bit samples): say what it holds
        if dtype is not None and dtype != np.uint8:
            raise ValueError(f"{p.name}: expected unsigned 8-bit samples, got {dtype} samples (TIFF); convert it to "
                             f"8-bit first") from err
        raise ValueError(f"cannot read {p.name} as an image ({err})") from err
    except Image.DecompressionBombError as err:  # over twice Pillow's pixel limit (not an OSError)
        raise ValueError(f"cannot read {p.name}: {err}; reduce the photograph first") from err
    return a


def non_srgb_profile(path) -> str | None:
    """The description of a photograph's embedded ICC profile when it is not sRGB, or of a PNG's gAMA or cHRM that
    are not sRGB's (without an sRGB or ICC chunk, as :func:`read_image` decodes them), else None (no profile: read as
    sRGB, as :func:`read_rgb8`'s callers do; or an sRGB one). A matrix profile is sRGB when its red, green and blue
    colorants (D50 XYZ) are littleCMS's sRGB's within 0.005 (Display P3's red is 0.08 off, Adobe RGB's 0.17); a
    profile without colorants (a LUT profile) is not recognised as sRGB. Pillow's ImageCms (littleCMS) reads it."""
    import warnings

    from PIL import Image

    with warnings.catch_warnings():  # (the header only; Pillow's size warning names no file: set before opening)
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        with Image.open(path) as im:
            data = im.info.get("icc_profile")
            png = im.format == "PNG" and not data and "srgb" not in im.info
            colour = {k: im.info[k] for k in ("chromaticity", "gamma") if k in im.info} if png else {}
    if colour:  # a PNG's gAMA / cHRM, as read_image reads them (a linear gAMA 1.0 PNG was lifted as sRGB, unsaid)
        try:
            exponent = _png_decode_exponent(Path(path), colour)
        except ValueError:
            return "PNG cHRM chromaticities other than sRGB's"
        if exponent is not None:
            return f"PNG gAMA {float(colour['gamma']):g} (code values decode as code^{exponent:.3g}, not sRGB)"
    return _non_srgb_icc(data)


def non_srgb_photos(files) -> str | None:
    """A sentence naming the photographs among ``files`` whose colour tags are not sRGB's (:func:`non_srgb_profile`;
    the first three), or None: the photo lifter reads every photograph's code values as sRGB, so their colours are not
    the photograph's. Unreadable files are skipped (their reader names them)."""
    other = []
    for f in files:
        try:
            name = non_srgb_profile(f)
        except Exception:  # noqa: BLE001  (a note only: an unreadable or oversized file is the reader's to name)
            continue
        if name is not None:
            other.append((Path(f).name, name))
    if not other:
        return None
    shown = ", ".join(f"{f} ({name})" for f, name in other[:3]) + (" ..." if len(other) > 3 else "")
    return (f"{len(other)} photograph(s) carry colour tags (an ICC profile, a PNG's gAMA or cHRM) that are not sRGB's: "
            f"{shown}; their code values are lifted as sRGB, so their colours are not the photograph's (convert them "
            f"to sRGB first)")


def _non_srgb_icc(data: bytes | None) -> str | None:
    """:func:`non_srgb_profile` of an embedded profile's bytes (None or empty: no profile)."""
    import io

    from PIL import ImageCms

    if not data:
        return None
    try:
        prof = ImageCms.ImageCmsProfile(io.BytesIO(data)).profile
    except (OSError, ImageCms.PyCMSError):
        return "an unreadable ICC profile"
    name = (prof.profile_description or "an unnamed ICC profile").strip()
    ours = [getattr(prof, f"{c}_colorant") for c in ("red", "green", "blue")]
    if any(c is None for c in ours):
        return name
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).profile
    ref = [getattr(srgb, f"{c}_colorant") for c in ("red", "green", "blue")]
    off = max(abs(a - b) for c, r in zip(ours, ref) for a, b in zip(c[0], r[0]))
    return None if off <= 0.005 else name


def _tiff_sample_type(p: Path):
    """The sample dtype of a TIFF's first image (tifffile reads what Pillow cannot), None for another file."""
    import logging

    log = logging.getLogger("tifffile")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)  # (its own error lines went to stderr beside the command's one line)
    try:
        import tifffile

        with tifffile.TiffFile(str(p)) as tif:
            return np.dtype(tif.series[0].dtype)
    except Exception:  # not a TIFF, or unreadable: the caller's message stands
        return None
    finally:
        log.setLevel(level)


def rgb8_to_tensor(array: np.ndarray) -> torch.Tensor:
    """8-bit sRGB code values ``[H, W, 3]`` (as :func:`read_rgb8` returns them) as float64 ``[1, 3, H, W]`` code
    values / 255: the scoring convention of ``shared/data``.

    Example:
        >>> rgb8_to_tensor(np.full((2, 2, 3), 255, dtype=np.uint8)).shape
        torch.Size([1, 3, 2, 2])
    """
    return torch.from_numpy(array.astype(np.float64) / 255.0).permute(2, 0, 1)[None]


def _kind(path: Path) -> str:
    kind = IMAGE_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"path: expected a file ending in one of {sorted(IMAGE_SUFFIXES)}, got {str(path)!r}")
    return kind


def _check_encoding(encoding: str) -> None:
    if encoding not in _ENCODINGS:
        raise ValueError(f"encoding: expected one of {_ENCODINGS}, got {encoding!r}")


def read_image(path, *, encoding: str = "srgb", dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Read an image file as a linear tensor ``[1, C, H, W]`` (C = the file's channels: 1, 2 (grey and alpha), 3 or 4),
    shown as it is displayed: a PNG's or TIFF's EXIF / TIFF orientation tag is applied, as :func:`read_rgb8` applies
    it. A PNG's stored samples are read at their full depth (an ``sBIT`` chunk, the significant bits of the source,
    is ignored as the PNG specification allows: the samples are already scaled to the full range).

    Args:
        path: a ``.png``, ``.tif``/``.tiff`` or ``.exr`` file.
        encoding: how an integer file's code values are encoded: ``"srgb"`` (default: decoded to linear) or
            ``"linear"`` (code / (2^bits - 1) as is). Float files (EXR, float TIFF) are linear either way.
        dtype: the returned floating dtype.

    Example:
        >>> img = read_image("photo.png")  # linear  # doctest: +SKIP
        >>> codes = read_image("photo.png", encoding="linear")  # the code values, for from_rgb  # doctest: +SKIP
        >>> scene = isettorch.scene.from_rgb(codes)  # doctest: +SKIP
    """
    from ..image import srgb_decode

    _check_encoding(encoding)
    if not (isinstance(dtype, torch.dtype) and dtype.is_floating_point):  # (uint8 returned zeros: values in [0, 1])
        raise TypeError(f"dtype: expected a floating torch.dtype, got {dtype!r}")
    p = Path(path)
    kind = _kind(p)
    if not p.is_file():
        raise FileNotFoundError(f"path: no such file {str(p)!r}")
    exponent = None  # decoded with the sRGB curve, or code ^ exponent (a PNG's gAMA)
    associated = kind == "exr"  # premultiplied alpha: OpenEXR's convention, a TIFF's ExtraSamples 1
    if kind == "exr":
        a = _read_exr(p, check_colours=encoding == "srgb")
    else:
        try:
            a, orientation, colour = _read_png(p) if kind == "png" else _read_tiff(p)
        except (ValueError, OSError, NotImplementedError) as err:  # (tifffile: packed 4 / 12-bit need imagecodecs)
            raise ValueError(f"path: {str(p)!r} is not a readable {kind.upper()} image ({err})") from err
        associated = bool(colour.pop("associated_alpha", False))
        if colour and encoding == "srgb":
            exponent = _png_decode_exponent(p, colour)
        if a.ndim in (2, 3) and orientation in _ORIENT:
            a = _ORIENT[orientation](a)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[-1] not in (1, 2, 3, 4):
        raise ValueError(f"path: {str(p)!r}: expected a gray, RGB or RGBA image, got array shape {a.shape}")
    t = torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None]
    if a.dtype.kind in "ui":
        bits = 8 * a.dtype.itemsize
        t = t.to(torch.float64) / (2**bits - 1)
    elif a.dtype.kind == "f":
        t = t.to(torch.float64)
        if not torch.isfinite(t).all():
            raise ValueError(f"path: {str(p)!r} holds non-finite values (NaN or inf)")
    else:
        raise ValueError(f"path: {str(p)!r}: unsupported sample type {a.dtype}")
    if associated and t.shape[1] in (2, 4):
        # straight alpha, as PNG's (the tensor's convention): colour / alpha where covered; a transparent pixel's
        # colour (alpha 0) is as stored (an emission-only pixel keeps its light). TIFF premultiplies the stored
        # values (TIFF 6.0, ExtraSamples; Pillow divides the codes), so this comes before the decoding: after it,
        # linear 0.2 at alpha 0.5 read as 0.096
        c = t.shape[1] - 1
        alpha = t[:, c:]
        t = torch.cat([torch.where(alpha > 0, t[:, :c] / torch.where(alpha > 0, alpha, 1.0), t[:, :c]), alpha], dim=1)
    if a.dtype.kind in "ui" and encoding == "srgb":
        # the colour channels; an alpha channel (the last of 2 or 4) is linear coverage
        c = t.shape[1] - (1 if t.shape[1] in (2, 4) else 0)
        decoded = srgb_decode(t[:, :c]) if exponent is None else t[:, :c] ** exponent
        t = torch.cat([decoded, t[:, c:]], dim=1)
    out = t.to(dtype)
    if dtype.itemsize < 8 and not bool(torch.isfinite(out).all()):  # (an EXR's 1e5 read as float16 was inf)
        raise ValueError(f"dtype: {str(p)!r} holds values up to {float(t.abs().max()):.6g}, beyond {dtype}'s "
                         f"range (max {torch.finfo(dtype).max:g}); read it as torch.float32")
    return out


def _read_png(p: Path) -> tuple[np.ndarray, int | None, dict]:
    """The samples ``[H, W, C]`` (uint8 or uint16), the EXIF orientation (None without one) and the colour chunks
    Pillow reads (:func:`_png_info`)."""
    import png  # pypng: 16-bit RGB, which Pillow reads as 8-bit

    try:
        with open(p, "rb") as fh:  # (Reader(filename=) left the file open until the reader was collected)
            reader = png.Reader(file=fh)
            reader.preamble()
            reader.sbit = None  # asDirect would shift the samples down to the sBIT depth (a 12-bit file's white: 4095)
            w, h, rows, info = reader.asDirect()  # palette and transparency expanded
            planes = info["planes"]
            a = np.vstack([np.asarray(r, dtype=np.uint16 if info["bitdepth"] > 8 else np.uint8) for r in rows])
    except (png.Error, EOFError) as err:  # (an empty file: EOFError, which named no path)
        raise ValueError(str(err) or type(err).__name__) from err
    a = a.reshape(h, w, planes)
    if info["bitdepth"] not in (8, 16):  # 1, 2, 4 bit gray: rescale to 8 bits (PNG 1.2, 12.5: code * 255 / max)
        a = np.round(a.astype(np.float64) * 255 / (2 ** info["bitdepth"] - 1)).astype(np.uint8)
    return (a, *_png_info(p))


def _png_info(p: Path) -> tuple[int | None, dict]:
    """A PNG's EXIF orientation (its eXIf chunk, or None) and its colour chunks as Pillow reads them:
    ``srgb`` (sRGB), ``icc_profile`` (iCCP), ``chromaticity`` (cHRM: white, red, green, blue x, y) and ``gamma``
    (gAMA)."""
    from PIL import PngImagePlugin

    # the header only, by the PNG plugin itself: Image.open refuses a file over twice its pixel limit
    # (DecompressionBombError), which pypng reads
    try:
        im = PngImagePlugin.PngImageFile(p)
    except SyntaxError as err:  # (Pillow's word for a chunk it cannot parse)
        raise ValueError(f"its chunks: {err}") from err
    with im:
        colour = {k: im.info[k] for k in ("srgb", "icc_profile", "chromaticity", "gamma") if k in im.info}
        try:
            return im.getexif().get(0x0112), colour
        except Exception:  # an EXIF block Pillow cannot parse: no orientation, as read_rgb8 then shows the stored rows
            return None, colour


#: gAMA 0.45455, the value sRGB files carry (PNG 3rd ed., 11.3.3.5): decoded with the sRGB curve
_SRGB_PNG_GAMMA = 0.45455


def _png_decode_exponent(p: Path, colour: dict) -> float | None:
    """How a PNG's code values decode to linear light: None for the sRGB curve (an sRGB chunk, an sRGB ICC profile,
    a gAMA of 0.45455 or no colour chunk: the convention of every viewer), else the exponent ``1 / gamma`` of its
    gAMA chunk (PNG 3rd ed., 11.3.3.2 and 13.13: linear = code ^ (1 / gamma); a gamma of 1 is linear). The sRGB
    chunk, then an ICC profile, take precedence over gAMA and cHRM (11.3.3.5). Colours other than sRGB's (a
    non-sRGB ICC profile, cHRM primaries or white beyond 0.001 of sRGB's) raise: decoding them with the sRGB
    curve and matrix would give wrong linear values, unsaid."""
    from ..image import D65_XY, SRGB_PRIMARIES_XY

    if "srgb" in colour:
        return None
    if "icc_profile" in colour:
        name = _non_srgb_icc(colour["icc_profile"])
        if name is not None:
            raise ValueError(f"path: {str(p)!r} carries the ICC profile {name!r}, not sRGB; read it with "
                             f"encoding='linear' (its code values) and convert them with that profile, or save the "
                             f"image as sRGB")
        return None
    chrm = colour.get("chromaticity")
    if chrm is not None:
        want = (*D65_XY, *(v for xy in SRGB_PRIMARIES_XY for v in xy))
        if max(abs(float(a) - b) for a, b in zip(chrm, want, strict=True)) > 1e-3:
            raise ValueError(f"path: {str(p)!r} has cHRM chromaticities {tuple(round(float(v), 4) for v in chrm)} "
                             f"(white, red, green, blue x, y), not sRGB's {want}; read it with encoding='linear' "
                             f"and convert its colours, or save the image as sRGB")
    gamma = colour.get("gamma")
    if gamma is None or abs(float(gamma) - _SRGB_PNG_GAMMA) <= 1e-5:
        return None
    if not float(gamma) > 0:
        raise ValueError(f"path: {str(p)!r} has a gAMA of {gamma!r}; expected a positive gamma")
    return 1.0 / float(gamma)


def _read_tiff(p: Path, photometric: tuple[str, ...] = _TIFF_PHOTOMETRIC) -> tuple[np.ndarray, int, dict]:
    """The samples ``[H, W(, S)]``, the orientation tag (1 = as stored) and the colour tags (``icc_profile``;
    ``associated_alpha`` where the alpha is premultiplied); a photometric interpretation outside ``photometric``
    (tifffile's names) raises."""
    import tifffile

    with tifffile.TiffFile(str(p)) as tif:
        if not tif.series:  # (a corrupt file: tif.series[0] was a bare IndexError)
            raise ValueError("no image in the file")
        series = tif.series[0]
        axes, a = series.axes, series.asarray()
        page = tif.pages[0]
        tag = page.tags.get("Orientation")
        orientation = int(tag.value) if tag is not None else 1
        icc = page.tags.get(34675)  # InterColorProfile (TIFF/EP; ICC.1 annex B): a 16-bit Adobe RGB or ProPhoto
        icc = bytes(icc.value) if icc is not None else None
        extra = page.tags.get("ExtraSamples")  # TIFF 6.0: 1 is associated (premultiplied) alpha, 2 unassociated
        associated = extra is not None and 1 in np.atleast_1d(np.asarray(extra.value)).tolist()
        # no PhotometricInterpretation tag (tifffile's 0): the samples as they are, as read before
        kind = getattr(page.photometric, "name", None) if page.tags.get("PhotometricInterpretation") else None
    if kind is not None and kind not in photometric:
        raise ValueError(f"expected photometric interpretation {' or '.join(photometric)}, got {kind} (its stored "
                         "numbers are not the image's values); convert the file first")
    # one image, samples last: a planar ('SYX') file came back channels first and two grey pages as one RGB image
    # when they were 4 pixels wide or less
    if any(ax not in "YXS" for ax in axes):
        raise ValueError(f"expected one image (axes Y, X and samples S), got a TIFF series with axes {axes!r} "
                         f"(pages, planes or depth); save each image as its own file")
    if "S" in axes:
        a = np.moveaxis(a, axes.index("S"), -1)
    if a.dtype == np.float16:
        a = a.astype(np.float32)
    if a.dtype not in (np.uint8, np.uint16, np.float32, np.float64):  # (float64 kept: 1e39 narrowed to inf)
        raise ValueError(f"expected uint8, uint16, float16, float32 or float64 samples, got {a.dtype}")
    colour = {"icc_profile": icc} if icc is not None else {}
    if associated:
        colour["associated_alpha"] = True
    return a, orientation, colour


def _read_exr(p: Path, check_colours: bool = True) -> np.ndarray:
    """The R, G, B(, A) or Y(, A) channels ``[H, W, C]``: float32, or float64 where a channel is (UINT).

    A luminance / chroma file (``Y``, ``RY``, ``BY``: OpenEXR's ``WRITE_YC``) raises (its colour was dropped as
    grey); so do, with ``check_colours``, ``chromaticities`` other than Rec. 709 / sRGB's (ACES2065-1's AP0 read as
    sRGB was 0.38 off in red), as a PNG's cHRM does."""
    from .exr import _exr_channels

    header, chans = _exr_channels(p)
    if "RY" in chans or "BY" in chans:
        raise ValueError(f"path: {str(p)!r} is a luminance / chroma OpenEXR (channels Y, RY, BY); convert it to R, G, "
                         "B channels first (e.g. OpenEXR's RgbaInputFile)")
    chrm = header.get("chromaticities")
    if check_colours and chrm is not None:
        from ..image import D65_XY, SRGB_PRIMARIES_XY

        # OpenEXR's order: red, green, blue, white (x, y)
        want = (*(v for xy in SRGB_PRIMARIES_XY for v in xy), *D65_XY)
        if max(abs(float(a) - b) for a, b in zip(chrm, want, strict=True)) > 1e-3:
            raise ValueError(f"path: {str(p)!r} has chromaticities {tuple(round(float(v), 4) for v in chrm)} (red, "
                             f"green, blue, white x, y), not Rec. 709 / sRGB's {tuple(round(v, 4) for v in want)}; "
                             "read it with encoding='linear' (its stored values) and convert its colours, or save "
                             "it in sRGB primaries")
    for names in (("R", "G", "B", "A"), ("R", "G", "B"), ("Y", "A"), ("Y",)):
        if all(n in chans for n in names):
            a = np.stack([chans[n] for n in names], axis=-1)  # (half and float channels together: float32)
            return a if a.dtype == np.float64 else a.astype(np.float32)
    raise ValueError(f"path: {str(p)!r} has no R, G, B (or Y) channels (channels: {sorted(chans)[:8]}); a spectral "
                     "EXR reads with isettorch.io.read_spectral_exr")


def write_image(path, image: torch.Tensor, *, encoding: str = "srgb", bits: int | None = None,
                clip: bool = False) -> list[Path]:
    """Write a linear image ``[C, H, W]`` or ``[B, C, H, W]`` to PNG, TIFF or EXR: C = 1 (grey), 3 (RGB), or 2 or 4
    with a last alpha channel.

    Args:
        path: the file; for a batch (B > 1) a pattern with an ``{i}`` field, one file per sample
            (``"img_{i:03d}.png"``).
        image: linear values, white = 1.
        encoding: for integer files, ``"srgb"`` (default: sRGB-encode the linear values, IEC 61966-2-1) or
            ``"linear"`` (store the linear values as code values). Float files are always linear.
        bits: PNG 8 (default) or 16; TIFF 8 (default), 16 or 32 (float32); EXR 16 (half) or 32 (default).
        clip: clip values outside [0, 1] for integer files instead of raising.

    Returns the written paths.
    """
    from ..image import srgb_encode

    _check_encoding(encoding)
    check_bool(clip, "clip")  # (clip='no' clipped; checked whatever the values, not only when they need it)
    if not isinstance(image, torch.Tensor):
        raise TypeError(f"image: expected a torch.Tensor [C, H, W] or [B, C, H, W], got {type(image).__name__}")
    x = image.detach()
    if x.dim() == 3:
        x = x[None]
    if x.dim() != 4 or x.shape[1] not in (1, 2, 3, 4):
        raise ValueError(f"image: expected [C, H, W] or [B, C, H, W] with C in (1, 2, 3, 4), got "
                         f"{tuple(image.shape)}")
    if not torch.isfinite(x).all():
        raise ValueError("image: expected finite values (found NaN or inf)")
    template = os.fspath(path)
    if x.shape[0] > 1 and "{i" not in template:
        raise ValueError(f"path: image is a batch of {x.shape[0]}; give a path with an {{i}} field (e.g. "
                         f"'img_{{i:03d}}.png') to write one file per sample, or write image[k] for one sample")
    kind = _kind(Path(template.replace("{", "").replace("}", "")))
    allowed = {"png": (8, 16), "tiff": (8, 16, 32), "exr": (16, 32)}[kind]
    bits = bits if bits is not None else (32 if kind == "exr" else 8)
    if bits not in allowed:
        raise ValueError(f"bits: expected one of {allowed} for {kind.upper()}, got {bits!r}")
    integer = bits in (8, 16) and kind != "exr"
    x = x.to(torch.float64).cpu()
    if integer:
        lo, hi = float(x.min()), float(x.max())
        if (lo < 0 or hi > 1) and not clip:
            raise ValueError(f"image: values span [{lo:.4g}, {hi:.4g}], outside [0, 1] for a {bits}-bit file; scale "
                             "the image (white = 1), pass clip=True, or write a float file (EXR, 32-bit TIFF)")
        x = x.clamp(0, 1)
        if encoding == "srgb":  # the colour channels; an alpha channel (the last of C = 2 or 4) is linear coverage
            colour = x.shape[1] - (1 if x.shape[1] in (2, 4) else 0)
            x = torch.cat([srgb_encode(x[:, :colour]), x[:, colour:]], dim=1)
        x = (x * (2**bits - 1)).round().to(torch.int64)
    # the whole batch in the file's sample type before any file is written; a float file is checked for overflow
    # only: values below half's 6e-8 (of white = 1) rounding to 0 is its precision, not lost data
    file_type = ({8: np.uint8, 16: np.uint16}[bits] if integer
                 else np.float16 if bits == 16 else np.float32)
    samples = x.permute(0, 2, 3, 1).numpy()
    samples = samples.astype(file_type) if integer else narrow_float(samples, file_type, "image")
    written = []
    # each file under a temporary name, all moved into place at the end: a failure (a missing folder for file 3,
    # a full disk) leaves no file of the batch written and none overwritten
    with Outputs() as staged:
        for i, a in enumerate(samples):
            p = Path(template.format(i=i)) if "{i" in template else Path(template)
            tmp = staged.temporary(p)
            if kind == "png":
                _write_png(tmp, a, bits, linear=encoding == "linear")
            elif kind == "tiff":
                import tifffile

                c = a.shape[-1]
                tifffile.imwrite(str(tmp), a[..., 0] if c == 1 else a, photometric="minisblack" if c <= 2 else "rgb",
                                 extrasamples=["unassalpha"] if c in (2, 4) else None)
            else:
                _write_exr(tmp, a)
            written.append(p)
    return written


def _write_png(p: Path, a: np.ndarray, bits: int, linear: bool = False) -> None:
    import png

    h, w, c = a.shape
    # linear code values carry a gAMA of 1 (PNG 3rd ed., 11.3.3.2), which read_image and viewers honour: without it
    # every reader takes them as sRGB (a linear 0.5 read back as 0.216)
    writer = png.Writer(width=w, height=h, greyscale=c <= 2, alpha=c in (2, 4), bitdepth=bits,
                        gamma=1.0 if linear else None)
    with open(p, "wb") as fh:
        writer.write(fh, a.reshape(h, w * c))


def _write_exr(p: Path, a: np.ndarray) -> None:
    import OpenEXR

    names = _EXR_CHANNELS[a.shape[-1]]
    if a.shape[-1] in (2, 4):  # OpenEXR stores colour premultiplied by alpha (Technical Introduction)
        a = np.concatenate([a[..., :-1] * a[..., -1:], a[..., -1:]], axis=-1).astype(a.dtype, copy=False)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {n: np.ascontiguousarray(a[..., k]) for k, n in enumerate(names)}).write(str(p))
