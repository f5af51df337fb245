"""A folder of the user's own RGB photos as a source of spectral scenes (for users who want their own domain; the
shipped models use no real photo).

Each photo is decoded from sRGB (IEC 61966-2-1) to linear values, taken as the reflectance of a surface seen under a
random illuminant, and lifted to spectra with ``colour.recovery``'s linear sRGB basis (Mallett & Yuksel, EGSR 2019,
:func:`.spectra.srgb_basis_spectra`): ``R(x, l) = sum_c rgb_c(x) B_c(l)``, in [0, 1] to 1e-8 (the basis' three spectra
sum to 1 + 6.2e-9 at most, colour-science's tabulated values: a white reads 1.0000000062). The scene is factored (three
maps, three spectra), like :func:`.natural.generate_natural`, so :func:`.natural.to_scene` makes it a factored
:class:`~isettorch.scene.Scene` for a :class:`~isettorch.camera.Camera`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .._checks import check_seed, check_wavelengths, dataset_index, is_integer, is_real, warn_caller
from ..io.images import PHOTO_SUFFIXES, non_srgb_photos, photo_files, read_rgb8, rgb8_to_tensor
from . import spectra as _spectra
from .config import seed_for
from .natural import _choice, natural_config
from .scenes import _white_photons

__all__ = ["PhotoSceneDataset", "lift_srgb"]


#: the wavelengths Mallett & Yuksel's basis covers (``colour.recovery``); beyond them it is 0: a white reflects nothing
BASIS_RANGE_NM = (380.0, 780.0)


def _lift_grid(wavelengths_nm) -> torch.Tensor:
    """The lift's wavelength grid (float64): a tensor is the grid itself; anything else ``(start, stop, step)``,
    inclusive (the configs' form), with some wavelength within :data:`BASIS_RANGE_NM`. A list of three wavelengths
    read as ``(start, stop, step)`` gave a one-sample grid, 31 values a bare unpacking error, a reversed range
    torch's own."""
    from ..spectral import default_wavelengths

    if isinstance(wavelengths_nm, torch.Tensor):
        w = check_wavelengths(wavelengths_nm.detach().to(torch.float64).cpu().reshape(-1), "wavelengths_nm")
    else:
        seq = list(wavelengths_nm) if isinstance(wavelengths_nm, (list, tuple, np.ndarray)) else None
        if not (seq is not None and len(seq) == 3 and all(is_real(v) for v in seq) and seq[2] > 0
                and seq[0] <= seq[1] and (seq[0] == seq[1] or seq[2] <= seq[1] - seq[0])):
            raise ValueError(f"wavelengths_nm: expected (start, stop, step) in nm with start <= stop and 0 < step <= "
                             f"stop - start, or a tensor of the wavelengths themselves, got {wavelengths_nm!r}")
        w = default_wavelengths(*(float(v) for v in seq), dtype=torch.float64)
    lo, hi = BASIS_RANGE_NM
    if not bool(((w >= lo) & (w <= hi)).any()):  # (a grid of 300-370 nm lifted a white to nothing)
        raise ValueError(f"wavelengths_nm: expected wavelengths within {lo:g}-{hi:g} nm (the sRGB basis' range; "
                         f"beyond it the basis is 0: a photograph carries no light there), got {float(w.min()):g}-"
                         f"{float(w.max()):g} nm")
    return w


def lift_srgb(image, wavelengths_nm=(400.0, 700.0, 10.0)) -> dict:
    """A photograph as a factored reflectance (the lift :class:`PhotoSceneDataset` applies to its crops).

    ``image``: 8-bit ``uint8 [H, W, 3]`` (as read from a file) or encoded sRGB in [0, 1] ``[3, H, W]``. It is decoded
    (IEC 61966-2-1) to linear sRGB ``c(x)`` and lifted with Mallett & Yuksel's basis (EGSR 2019,
    :func:`.spectra.srgb_basis_spectra`): ``R(x, l) = sum_c c_c(x) B_c(l)``, in [0, 1] (to 1e-8, as above), whose sRGB
    under D65 is ``c`` on the basis' own 380-780 nm grid (mean dE2000 0.001); on the 400-700 nm, 10 nm grid of the
    configs the round trip (D65, CIE 1931 CMFs on that grid, white normalised by Y) is within dE2000 0.73 (mean 0.22
    over the 8-bit cube in steps of 5; a white reads linear (0.998, 1.001, 0.998), dE2000 0.31: the truncated grid's
    white is not quite D65's), the largest code-value errors in near-zero channels of saturated colours, where the sRGB
    curve is steep (up to 25 codes: (25, 240, 245) returns as (0, 240, 245)). Colours outside sRGB cannot be
    represented. ``wavelengths_nm``: ``(start, stop, step)`` in nm, inclusive, or a tensor of the wavelengths, some of
    them within 380-780 nm (beyond, the basis and so the reflectance are 0: a photograph carries no light there).
    Returns ``{"maps": [3, H, W] float64 linear sRGB, "reflectance": [3, L] float64 basis, "wavelengths_nm": [L]}``;
    multiply the reflectance by an illuminant's photons for a scene's spectra.
    """
    from ..image import srgb_decode

    if isinstance(image, np.ndarray):
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"image: expected a uint8 [H, W, 3] array, got {image.dtype} {image.shape}")
        enc = rgb8_to_tensor(image)[0]
    else:
        if isinstance(image, torch.Tensor) and not image.is_floating_point():
            # (uint8 codes 0 and 1 passed the [0, 1] check as values: code 1 was lifted as white; from_rgb's rule)
            raise TypeError(f"image: expected encoded sRGB floats in [0, 1] [3, H, W] (or a uint8 [H, W, 3] numpy "
                            f"array), got a {image.dtype} tensor; convert 8-bit codes with image.double() / 255")
        enc = torch.as_tensor(image, dtype=torch.float64)
        if enc.dim() != 3 or enc.shape[0] != 3 or min(enc.shape[1:]) < 1:
            raise ValueError(f"image: expected encoded sRGB [3, H, W], got shape {tuple(enc.shape)}")
        if not bool(((enc >= 0) & (enc <= 1)).all()):
            raise ValueError("image: expected encoded sRGB values in [0, 1]")
    wl = _lift_grid(wavelengths_nm)
    return {"maps": srgb_decode(enc).clamp(0, 1), "reflectance": _spectra.srgb_basis_spectra(wl).to(torch.float64),
            "wavelengths_nm": wl}


class PhotoSceneDataset(torch.utils.data.Dataset):
    """Random ``size`` x ``size`` crops of the 8-bit RGB photos in ``folder`` (png/tif/jpg), lifted to spectra.

    Item ``i`` is photo ``i % len(photos)`` with a crop, flip and illuminant drawn from ``(seed, i)``; it returns
    the factored scene dict of :func:`.natural.generate_natural`.

    Args:
        folder: images (sorted by name). length: items (default: one per photo).
        size: crop size in pixels (photos smaller than that raise an error naming the file).
        illuminants: kind weights for :func:`.spectra.random_illuminant`.
    """

    SUFFIXES = PHOTO_SUFFIXES

    def __init__(self, folder, size: int = 128, *, length: int | None = None, seed: int = 0,
                 wavelengths_nm=(400.0, 700.0, 10.0), illuminants: dict | None = None):
        folder = Path(folder)
        if not folder.is_dir():
            raise ValueError(f"folder: expected a directory of RGB photos, got {str(folder)!r}")
        if not (is_integer(size) and size >= 2):  # (0 gave empty scenes, 2.7 was cut to 2)
            raise ValueError(f"size: expected an integer crop size >= 2 pixels, got {size!r}")
        if length is not None and not (is_integer(length) and length >= 1):  # (-3 failed later, inside len())
            raise ValueError(f"length: expected None or an integer >= 1, got {length!r}")
        check_seed(seed)  # (-1 gave the items of 2^64 - 1)
        self.files = photo_files(folder)
        if not self.files:
            raise ValueError(f"folder: no {'/'.join(self.SUFFIXES)} files in {str(folder)!r}")
        note = non_srgb_photos(self.files)  # (design-eval said so; training on them did not)
        if note is not None:
            warn_caller(f"folder: {note}")
        self.size, self.seed = int(size), int(seed)
        self.length = len(self.files) if length is None else int(length)
        self.wl = _lift_grid(wavelengths_nm)
        default = natural_config()["components"]["illuminant"]["kinds"]
        if illuminants is not None:  # checked as the natural generator's kinds ('candle' and NaN failed in ds[0],
            # naming 'kind' or 'weights'; a negative weight was read as 0)
            if not isinstance(illuminants, dict):
                raise ValueError(f"illuminants: expected a dict of kind weights, got {illuminants!r}")
            try:
                natural_config({"components": {"illuminant": {"kinds": dict(illuminants)}}})
            except ValueError as err:
                raise ValueError(f"illuminants: {str(err).split(': ', 2)[-1]}") from None
        self.illuminants = dict(illuminants or default)
        self.basis = _spectra.srgb_basis_spectra(self.wl)

    def __len__(self) -> int:
        return self.length

    def _photo(self, path: Path) -> torch.Tensor:
        from ..image import srgb_decode

        try:
            a = read_rgb8(path).astype(np.float64) / 255.0
        except ValueError as err:
            raise ValueError(f"folder: {err}") from err
        if min(a.shape[:2]) < self.size:
            raise ValueError(f"size: {path.name} is {a.shape[1]} x {a.shape[0]}, smaller than the crop {self.size}")
        return srgb_decode(torch.from_numpy(a).permute(2, 0, 1))

    def __getitem__(self, index: int) -> dict:
        index = dataset_index(index, self.length)
        g = torch.Generator().manual_seed(seed_for(self.seed, index))
        path = self.files[index % len(self.files)]
        lin = self._photo(path)
        h, w = lin.shape[-2:]
        y = int(torch.randint(0, h - self.size + 1, (), generator=g))
        x = int(torch.randint(0, w - self.size + 1, (), generator=g))
        crop = lin[:, y:y + self.size, x:x + self.size]
        if float(torch.rand((), generator=g, dtype=torch.float32)) < 0.5:
            crop = crop.flip(-1)
        kind = _choice(self.illuminants, g)
        spd, cct, name = _spectra.random_illuminant(kind, self.wl, g)
        e = _white_photons(spd, self.wl)
        meta = {"index": int(index), "seed": self.seed, "photo": path.name, "crop_yx": (y, x), "illuminants": [name],
                "cct_k": float(cct)}
        return {"maps": crop.clamp(0, 1).float(), "spectra": self.basis * e[None], "wavelengths_nm": self.wl,
                "illuminant": e, "meta": meta}
