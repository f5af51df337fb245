"""`SpectralImage`: the batched spectral cube shared by `Scene` and `OpticalImage`.

Layout ``photons [B, L, H, W]`` (batch, wavelength, rows, cols), row 0 at the top; wavelengths
``[L]`` in nm. Per-sample scalars (FOV, distance, ...) are tensors of shape ``[B]`` in the
photons' dtype and device, so they broadcast over the batch.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import torch

from . import spectral
from ._checks import batch_param, check_nonnegative, check_rank, check_wavelengths

# IEC 61966-2-1:1999 (sRGB), XYZ (D65, Y = 1) -> linear sRGB.
XYZ_TO_LINEAR_SRGB = (
    (3.2404542, -1.5371385, -0.4985314),
    (-0.9692660, 1.8760108, 0.0415560),
    (0.0556434, -0.2040259, 1.0572252),
)


def srgb_encode(linear: torch.Tensor, *, clip: bool = True, inplace: bool = False,
                out: torch.Tensor | None = None) -> torch.Tensor:
    """IEC 61966-2-1 sRGB encoding, linear -> encoded: ``12.92 x`` up to 0.0031308, ``1.055 x^(1/2.4) - 0.055`` above.

    The one clipping rule (every sRGB encoding in isettorch is this function): values below 0, outside the
    curve's domain, become 0; values above 1 (above white) become 1 when ``clip`` (the default), else follow the
    same power law (headroom above white is kept).

    ``inplace=True`` uses ``linear`` as scratch space (its values are overwritten) and fewer temporaries: bitwise
    the same result, ~2x faster on CPU; not for tensors that need gradients. ``out``: write the result there
    (same shape; ``linear`` is left unchanged), with fewer passes still; also bitwise the same.

    Example:
        >>> srgb_encode(torch.tensor([-0.5, 0.0, 0.5, 1.0, 2.0]))
        tensor([0.0000, 0.0000, 0.7354, 1.0000, 1.0000])
    """
    hi = 1.0 if clip else None
    low = linear <= 0.0031308
    if out is not None:
        torch.clamp(linear, 0.0031308, hi, out=out).pow_(1 / 2.4).mul_(1.055).sub_(0.055)
        return out.masked_scatter_(low, linear.masked_select(low).clamp_min_(0).mul_(12.92))
    if inplace:
        out = linear.clamp(0.0031308, hi).pow_(1 / 2.4).mul_(1.055).sub_(0.055)
        return torch.where(low, linear.clamp_min_(0).mul_(12.92), out, out=out)
    return torch.where(low, 12.92 * linear.clamp_min(0), 1.055 * linear.clamp(0.0031308, hi) ** (1 / 2.4) - 0.055)


def srgb_decode(encoded: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 sRGB decoding, encoded -> linear: ``x / 12.92`` up to 0.04045, ``((x + 0.055) / 1.055)^2.4``
    above (differentiable: no pow at 0). No clipping: the inverse of :func:`srgb_encode` on [0, 1] and above."""
    return torch.where(encoded <= 0.04045, encoded / 12.92, ((encoded.clamp_min(0.04045) + 0.055) / 1.055) ** 2.4)


def xyz_to_srgb_preview(xyz_img: torch.Tensor, white_y: torch.Tensor) -> torch.Tensor:
    """Display preview: XYZ [B, 3, H, W] scaled so ``white_y`` [B] maps to 1, to encoded sRGB in [0, 1]."""
    m = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=xyz_img.dtype, device=xyz_img.device)
    scaled = xyz_img / white_y.reshape(-1, 1, 1, 1).clamp_min(torch.finfo(xyz_img.dtype).tiny)
    lin = torch.einsum("ij,bjhw->bihw", m, scaled)
    return srgb_encode(lin)


@dataclasses.dataclass(eq=False, repr=False)
class SpectralImage:
    """Base of `Scene` and `OpticalImage`: photons [B, L, H, W] on a wavelength grid [L] (nm)."""

    photons: torch.Tensor
    wavelengths_nm: torch.Tensor
    name: str = ""
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)
    validate: dataclasses.InitVar[bool] = True

    # names of per-sample [B] fields in subclasses
    _batch_fields: ClassVar[tuple[str, ...]] = ()
    _units: ClassVar[str] = "photons"

    def __post_init__(self, validate: bool = True) -> None:
        p = self.photons
        if not isinstance(p, torch.Tensor):
            raise TypeError(f"photons: expected a torch.Tensor [B, L, H, W], got {type(p).__name__}")
        if p.dim() == 3:
            p = p.unsqueeze(0)
        check_rank(p, 4, "photons", "[B, L, H, W] (or [L, H, W])")
        if not p.is_floating_point():
            p = p.to(torch.get_default_dtype())
        w = self.wavelengths_nm
        if not isinstance(w, torch.Tensor):
            w = torch.as_tensor(w, dtype=p.dtype)
        w = check_wavelengths(w.reshape(-1) if w.dim() == 0 else w)
        w = w.to(device=p.device, dtype=p.dtype)
        if w.numel() != p.shape[1]:
            raise ValueError(
                f"wavelengths_nm: expected {p.shape[1]} wavelengths to match photons' L dimension "
                f"(shape {tuple(p.shape)}), got {w.numel()}"
            )
        if validate:
            check_nonnegative(p.detach(), "photons")
        self.photons = p
        self.wavelengths_nm = w
        for f in self._batch_fields:
            v = getattr(self, f)
            if v is not None:
                setattr(self, f, batch_param(v, f, p.shape[0], dtype=p.dtype, device=p.device,
                                             positive=True))

    # --- shape and device -------------------------------------------------------------
    @property
    def batch_size(self) -> int:
        return self.photons.shape[0]

    @property
    def num_wavelengths(self) -> int:
        return self.photons.shape[1]

    @property
    def height(self) -> int:
        return self.photons.shape[2]

    @property
    def width(self) -> int:
        return self.photons.shape[3]

    @property
    def device(self) -> torch.device:
        return self.photons.device

    @property
    def dtype(self) -> torch.dtype:
        return self.photons.dtype

    def replace(self, **changes) -> SpectralImage:
        """A copy with some fields changed (validation is skipped for internal, trusted changes).

        :meth:`Scene.replace <isettorch.scene.Scene.replace>` validates by default (a user's edit of a scene).
        """
        changes.setdefault("validate", False)
        return dataclasses.replace(self, **changes)

    def _map_tensors(self, fn) -> dict[str, Any]:
        out = {}
        for f in dataclasses.fields(self):
            if not f.init:
                continue
            v = getattr(self, f.name)
            if isinstance(v, torch.Tensor):
                out[f.name] = fn(v)
        return out

    def to(self, device=None, dtype=None) -> SpectralImage:
        """Move to a device and/or floating dtype (all tensors together)."""
        return self.replace(**self._map_tensors(lambda t: t.to(device=device, dtype=dtype)
                                                if t.is_floating_point() else t.to(device=device)), validate=False)

    def detach(self) -> SpectralImage:
        return self.replace(**self._map_tensors(lambda t: t.detach()), validate=False)

    def __getitem__(self, index) -> SpectralImage:
        """Select batch samples: ``img[0]``, ``img[1:3]``; the batch dimension is kept."""
        if isinstance(index, int):
            index = slice(index, index + 1 if index != -1 else None)
        changes = {"photons": self.photons[index]}
        for f in self._batch_fields:
            v = getattr(self, f)
            if v is not None:
                changes[f] = v[index]
        if getattr(self, "illuminant_photons", None) is not None:
            changes["illuminant_photons"] = self.illuminant_photons[index]
        return self.replace(**changes, validate=False)

    def __repr__(self) -> str:
        extra = ", ".join(
            f"{f}={getattr(self, f).tolist() if getattr(self, f) is not None else None}" for f in self._batch_fields
        )
        w = self.wavelengths_nm
        return (
            f"{type(self).__name__}(name={self.name!r}, photons={tuple(self.photons.shape)} {self.dtype} "
            f"on {self.device}, wavelengths={w[0].item():g}..{w[-1].item():g} nm ({w.numel()}), {extra})"
        )

    # --- spectral ----------------------------------------------------------------------
    def resample_wavelengths(self, wavelengths_nm) -> SpectralImage:
        """Linear interpolation onto another grid (0 outside the current range)."""
        new = check_wavelengths(torch.as_tensor(wavelengths_nm)).to(self.device, self.dtype)
        changes = {"photons": spectral.resample(self.photons, self.wavelengths_nm, new, dim=1),
                   "wavelengths_nm": new}
        if getattr(self, "illuminant_photons", None) is not None:
            changes["illuminant_photons"] = spectral.resample(self.illuminant_photons, self.wavelengths_nm, new)
        return self.replace(**changes, validate=False)  # linear interpolation of checked data

    def energy(self) -> torch.Tensor:
        """Spectral image in energy units (W instead of photons/s)."""
        return spectral.photons_to_energy(self.photons, self.wavelengths_nm, dim=1)

    def photometric(self) -> torch.Tensor:
        """683 * sum E V dl: luminance (cd/m^2) of a scene, illuminance (lux) of an OI [B, 1, H, W]."""
        return spectral.luminance(self.photons, self.wavelengths_nm, dim=1)

    def xyz(self, observer: str = "1931") -> torch.Tensor:
        """Absolute CIE XYZ [B, 3, H, W] (Y in cd/m^2 for a scene, lux for an optical image)."""
        return spectral.xyz(self.photons, self.wavelengths_nm, dim=1, observer=observer)

    def _preview_white_y(self, xyz_img: torch.Tensor) -> torch.Tensor:
        return xyz_img[:, 1].flatten(1).amax(dim=1)

    def srgb(self) -> torch.Tensor:
        """Encoded sRGB preview [B, 3, H, W] in [0, 1]: XYZ scaled so the white (the illuminant for a
        scene that has one, else the brightest pixel) has Y = 1, IEC 61966-2-1 matrix and curve."""
        x = self.xyz()
        return xyz_to_srgb_preview(x, self._preview_white_y(x))

    def mean_spectrum(self, rows: slice | None = None, cols: slice | None = None) -> torch.Tensor:
        """Mean photons of a region [B, L] (rows/cols are slices; default the whole image)."""
        r = rows or slice(None)
        c = cols or slice(None)
        return self.photons[:, :, r, c].mean(dim=(-2, -1))

    def _crop_photons(self, top: int, left: int, height: int, width: int) -> torch.Tensor:
        if not (0 <= top and 0 <= left and height >= 1 and width >= 1
                and top + height <= self.height and left + width <= self.width):
            raise ValueError(
                f"crop: window top={top}, left={left}, height={height}, width={width} does not fit in an "
                f"image of {self.height}x{self.width}"
            )
        return self.photons[:, :, top:top + height, left:left + width]

    # --- plots -------------------------------------------------------------------------
    def plot_srgb(self, index: int = 0, ax=None):
        """Show the sRGB preview of sample ``index``; returns the matplotlib figure."""
        from .plot import show_image

        return show_image(self.srgb()[index], title=self.name or type(self).__name__, ax=ax)

    def plot_spectrum(self, rows: slice | None = None, cols: slice | None = None, index: int = 0, ax=None):
        """Plot the mean spectral photons of a region; returns the matplotlib figure."""
        from .plot import plot_spectrum

        spd = self.mean_spectrum(rows, cols)[index]
        return plot_spectrum(self.wavelengths_nm, spd, ylabel=f"mean {self._units}", ax=ax,
                             title=self.name or type(self).__name__)


def angle_for_extent(extent_m: torch.Tensor, distance_m: torch.Tensor) -> torch.Tensor:
    """Full angle (deg) subtended by ``extent_m`` centred at ``distance_m``: 2 atan(e / 2d)."""
    return torch.rad2deg(2 * torch.atan(extent_m / (2 * distance_m)))


def extent_for_angle(angle_deg: torch.Tensor, distance_m: torch.Tensor) -> torch.Tensor:
    """Extent (m) subtended by a full angle at a distance: 2 d tan(a / 2)."""
    return 2 * distance_m * torch.tan(torch.deg2rad(angle_deg) / 2)

