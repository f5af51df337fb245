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
from ._autograd import tensor_cache
from ._checks import (
    as_tensor,
    batch_param,
    check_bool,
    check_finite,
    check_nonnegative,
    check_rank,
    check_wavelengths,
    is_integer,
)

#: IEC 61966-2-1:1999 sRGB: the primaries' and the D65 white's CIE 1931 chromaticities
SRGB_PRIMARIES_XY = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
D65_XY = (0.3127, 0.3290)


def rgb_to_xyz_matrix(primaries_xy, white_xy) -> torch.Tensor:
    """Linear RGB -> XYZ ``(3, 3)`` float64 (columns: the primaries' XYZ; RGB (1, 1, 1) is the white with Y = 1) from
    the primaries' and the white's chromaticities (SMPTE RP 177-1993, section 3.3)."""
    p = torch.tensor([[x / y, 1.0, (1 - x - y) / y] for x, y in primaries_xy], dtype=torch.float64).T
    xw, yw = white_xy
    white = torch.tensor([xw / yw, 1.0, (1 - xw - yw) / yw], dtype=torch.float64)
    return p * torch.linalg.solve(p, white)[None, :]


def _srgb_constants() -> tuple[tuple, tuple]:
    m = rgb_to_xyz_matrix(SRGB_PRIMARIES_XY, D65_XY)
    return tuple(map(tuple, torch.linalg.inv(m).tolist())), tuple(m.sum(1).tolist())


# The one sRGB matrix of the library (IEC 61966-2-1:1999), XYZ (D65, Y = 1) -> linear sRGB: the inverse of the
# primaries' matrix (colour-science's ``normalised_primary_matrix`` to 1e-16), and the white it maps to (1, 1, 1),
# D65 at the standard's chromaticity (0.3127, 0.3290): XYZ (0.950456, 1, 1.089058).
XYZ_TO_LINEAR_SRGB, SRGB_WHITE_XYZ = _srgb_constants()


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
    if not linear.is_floating_point():  # (8-bit codes taken as linear values: 128 and 255 encoded to 1)
        raise TypeError(f"linear: expected a floating-point tensor of linear values, got {linear.dtype}")
    hi = 1.0 if check_bool(clip, "clip") else None  # (clip='no' clipped)
    low = linear <= 0.0031308
    if out is not None:
        torch.clamp(linear, 0.0031308, hi, out=out).pow_(1 / 2.4).mul_(1.055).sub_(0.055)
        # a where over the whole image (masked_select + masked_scatter_ were ~1.5x slower on CPU, measured)
        return torch.where(low, linear.clamp_min(0).mul_(12.92), out, out=out)
    if inplace:
        out = linear.clamp(0.0031308, hi).pow_(1 / 2.4).mul_(1.055).sub_(0.055)
        return torch.where(low, linear.clamp_min_(0).mul_(12.92), out, out=out)
    return torch.where(low, 12.92 * linear.clamp_min(0), 1.055 * linear.clamp(0.0031308, hi) ** (1 / 2.4) - 0.055)


def srgb_decode(encoded: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 sRGB decoding, encoded -> linear: ``x / 12.92`` up to 0.04045, ``((x + 0.055) / 1.055)^2.4``
    above (differentiable: no pow at 0). No clipping: the inverse of :func:`srgb_encode` on [0, 1] and above.
    ``encoded`` is floating point in [0, 1] units (8-bit codes: divide by 255 first)."""
    if not encoded.is_floating_point():  # (uint8 255 decoded to 524,947)
        raise TypeError(f"encoded: expected a floating-point tensor in [0, 1] units, got {encoded.dtype}")
    return torch.where(encoded <= 0.04045, encoded / 12.92, ((encoded.clamp_min(0.04045) + 0.055) / 1.055) ** 2.4)


# Bradford cone-response matrix (Lam 1985; CIE 159:2004).
_BRADFORD = ((0.8951, 0.2664, -0.1614), (-0.7502, 1.7135, 0.0367), (0.0389, -0.0685, 1.0296))


def bradford_matrix(source_white: torch.Tensor, target_white: torch.Tensor) -> torch.Tensor:
    """Chromatic adaptation ``(..., 3, 3)`` from ``source_white`` to ``target_white`` (XYZ ``(..., 3)``, any common
    scale; the two broadcast): ``M^-1 diag(M w_t / M w_s) M`` with the Bradford matrix M (von Kries in sharpened
    cone space; Lam 1985, as in CIE 160:2004 and colour-science's ``matrix_chromatic_adaptation_VonKries``)."""
    ws = as_tensor(source_white, "source_white", dtype=torch.float64)
    wt = as_tensor(target_white, "target_white", dtype=torch.float64).to(ws.device)
    m = torch.tensor(_BRADFORD, dtype=torch.float64, device=ws.device)  # on the whites' device (any device)
    for name, w in (("source_white", ws), ("target_white", wt)):
        if w.dim() == 0 or w.shape[-1] != 3:
            raise ValueError(f"{name}: expected XYZ values of shape (..., 3), got {tuple(w.shape)}")
        check_finite(w.detach(), name)
        if bool((w.detach()[..., 1] <= 0).any()):
            raise ValueError(f"{name}: expected a white with positive luminance Y, got {w.detach().tolist()}")
    gain = (wt @ m.T) / (ws @ m.T)  # cone-response ratios (..., 3)
    return _bradford_inverse().to(ws.device) @ (gain[..., :, None] * m)


@tensor_cache(maxsize=None)
def _bradford_inverse() -> torch.Tensor:
    return torch.linalg.inv(torch.tensor(_BRADFORD, dtype=torch.float64))


def xyz_to_srgb_preview(xyz_img: torch.Tensor, white_y: torch.Tensor) -> torch.Tensor:
    """Display preview: XYZ [B, 3, H, W] scaled so ``white_y`` [B] maps to 1, to encoded sRGB in [0, 1]."""
    m = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=xyz_img.dtype, device=xyz_img.device)
    scaled = xyz_img / white_y.reshape(-1, 1, 1, 1).clamp_min(torch.finfo(xyz_img.dtype).tiny)
    lin = torch.einsum("ij,bjhw->bihw", m, scaled)
    return srgb_encode(lin)



def select_items(values, index) -> list | None:
    """The entries of a per-item sequence (``SpectralFactors.terms``, an optical image's per-item OTF rows) for the
    items a batch ``index`` (int, slice, list, bool or long tensor) selects, in order; None for None. The one rule
    of the factored representations' ``select``."""
    if values is None:
        return None
    return [values[i] for i in torch.arange(len(values))[index].reshape(-1).tolist()]


def _check_window(top, left, height, width, image_height: int, image_width: int) -> None:
    """A crop window of whole samples inside an image of ``image_height x image_width`` (slicing would silently
    shorten one that reaches past the edge, or take 2.7 as a float index error)."""
    if not (all(is_integer(v) for v in (top, left, height, width)) and 0 <= top and 0 <= left and height >= 1
            and width >= 1 and top + height <= image_height and left + width <= image_width):
        raise ValueError(f"crop: window top={top}, left={left}, height={height}, width={width} does not fit in an "
                         f"image of {image_height}x{image_width}")


class SpectralFactors:
    """A low-rank spectral image ``radiance(b, l, y, x) = sum_j maps[b, j, y, x] * spectra[b, j, l]``.

    ``maps [B, J, H, W]`` and ``spectra [B, J, L]`` in the image's units (any split of the scale between them).
    The protocol every factored representation implements (see also the Fourier-domain factors of an
    optical image, :class:`isettorch.optics.optical_image.FourierFactors`): ``shape`` ``(B, H, W)``, ``dtype``,
    ``device``, ``project(weights [L, K]) -> [B, K, H, W]``, ``dense() -> [B, L, H, W]``, ``select(index)``,
    ``scale(k [B])``, ``to(device, dtype)``, ``detach()``; optional ``crop``, ``spectral_map``.

    ``terms`` (optional, B integers): item ``b``'s maps ``j >= terms[b]`` are exactly 0 (its used terms come first,
    e.g. a batch of items with different numbers of terms padded to the largest), so a consumer may leave them out
    (the optics transform only the used maps). A hint the producer guarantees; it does not change the radiance.
    """

    def __init__(self, maps: torch.Tensor, spectra: torch.Tensor, validate: bool = True, terms=None):
        if not isinstance(maps, torch.Tensor) or not isinstance(spectra, torch.Tensor):
            raise TypeError(f"maps, spectra: expected torch.Tensors, got {type(maps).__name__}, "
                            f"{type(spectra).__name__}")
        if maps.dim() == 3:
            maps = maps.unsqueeze(0)
        if spectra.dim() == 2:
            spectra = spectra.unsqueeze(0)
        check_rank(maps, 4, "maps", "[B, J, H, W] (or [J, H, W])")
        check_rank(spectra, 3, "spectra", "[B, J, L] (or [J, L])")
        if not maps.is_floating_point():
            maps = maps.to(torch.get_default_dtype())
        spectra = spectra.to(device=maps.device, dtype=maps.dtype)
        if spectra.shape[1] != maps.shape[1] or spectra.shape[0] not in (1, maps.shape[0]):
            raise ValueError(f"spectra: expected shape [{maps.shape[0]}, {maps.shape[1]}, L] to match maps "
                             f"{tuple(maps.shape)}, got {tuple(spectra.shape)}")
        if validate:
            check_nonnegative(maps.detach(), "maps")
            check_nonnegative(spectra.detach(), "spectra")
        self.maps = maps
        self.spectra = spectra.expand(maps.shape[0], -1, -1)
        if terms is not None:
            terms = tuple(int(t) for t in terms)
            if len(terms) != maps.shape[0] or any(not 0 <= t <= maps.shape[1] for t in terms):
                raise ValueError(f"terms: expected {maps.shape[0]} counts in [0, {maps.shape[1]}] (one per item), "
                                 f"got {terms}")
            if validate:
                j = torch.arange(maps.shape[1], device=maps.device)
                beyond = j[None, :] >= torch.tensor(terms, device=maps.device)[:, None]  # [B, J]
                if bool((maps.detach().flatten(2).abs().amax(-1) > 0)[beyond].any()):
                    raise ValueError("terms: a map beyond an item's term count is not 0 everywhere")
        self.terms = terms

    @property
    def shape(self) -> tuple[int, int, int]:
        b, _, h, w = self.maps.shape
        return b, h, w

    @property
    def rank(self) -> int:
        return self.maps.shape[1]

    @property
    def num_wavelengths(self) -> int:
        return self.spectra.shape[-1]

    @property
    def dtype(self) -> torch.dtype:
        return self.maps.dtype

    @property
    def device(self) -> torch.device:
        return self.maps.device

    def combine(self, coef: torch.Tensor) -> torch.Tensor:
        """``sum_j coef[b, j, k] maps[b, j]`` ``[B, K, H, W]`` for per-term coefficients ``coef [B, J, K]``."""
        b, j, h, w = self.maps.shape
        return (coef.transpose(1, 2) @ self.maps.reshape(b, j, h * w)).reshape(b, -1, h, w)

    def project(self, weights: torch.Tensor) -> torch.Tensor:
        """``sum_l radiance(l) weights[l, k]`` ``[B, K, H, W]`` without forming the ``[B, L, H, W]`` cube."""
        return self.combine(self.spectra @ weights.to(self.spectra))

    def spectral_map(self, fn) -> torch.Tensor:
        """A linear spectral functional ``fn(x, dim) `` (L -> K along ``dim``) of the radiance ``[B, K, H, W]``."""
        return self.combine(fn(self.spectra, -1))

    def dense(self) -> torch.Tensor:
        return self.combine(self.spectra)

    def select(self, index) -> SpectralFactors:
        return SpectralFactors(self.maps[index], self.spectra[index], validate=False,
                               terms=select_items(self.terms, index))

    def scale(self, k: torch.Tensor) -> SpectralFactors:
        """Radiance times ``k [B]`` (the spectra carry it)."""
        return SpectralFactors(self.maps, self.spectra * k.reshape(-1, 1, 1), validate=False, terms=self.terms)

    def multiply_spectra(self, s: torch.Tensor) -> SpectralFactors:
        """Radiance times a spectral factor ``s`` ``[L]`` or ``[B, L]``."""
        return SpectralFactors(self.maps, self.spectra * (s if s.dim() == 1 else s[:, None, :]), validate=False,
                               terms=self.terms)

    def crop(self, top: int, left: int, height: int, width: int) -> SpectralFactors:
        _check_window(top, left, height, width, *self.maps.shape[-2:])  # (a window past the edge was shortened)
        return SpectralFactors(self.maps[..., top:top + height, left:left + width], self.spectra, validate=False,
                               terms=self.terms)

    def resample(self, src_nm: torch.Tensor, dst_nm: torch.Tensor) -> SpectralFactors:
        """Linear interpolation onto another grid: it acts on the spectra only (it is linear)."""
        return SpectralFactors(self.maps, spectral.resample(self.spectra, src_nm, dst_nm, dim=-1), validate=False,
                               terms=self.terms)

    def to(self, device=None, dtype=None) -> SpectralFactors:
        return SpectralFactors(self.maps.to(device=device, dtype=dtype), self.spectra.to(device=device, dtype=dtype),
                               validate=False, terms=self.terms)

    def detach(self) -> SpectralFactors:
        return SpectralFactors(self.maps.detach(), self.spectra.detach(), validate=False, terms=self.terms)

    @staticmethod
    def cat(parts: list[SpectralFactors]) -> SpectralFactors:
        """Concatenate along the batch; ranks are padded with zero terms to the largest."""
        j = max(p.rank for p in parts)

        def pad(t, n):  # zero terms along dim 1
            return torch.cat([t, t.new_zeros(t.shape[0], n - t.shape[1], *t.shape[2:])], 1) if n > t.shape[1] else t
        terms = None
        if all(p.terms is not None for p in parts):
            terms = [t for p in parts for t in p.terms]
        return SpectralFactors(torch.cat([pad(p.maps, j) for p in parts]),
                               torch.cat([pad(p.spectra, j) for p in parts]), validate=False, terms=terms)

    def __repr__(self) -> str:
        return f"SpectralFactors(maps={tuple(self.maps.shape)}, spectra={tuple(self.spectra.shape)})"


def _trusted_batch(v, b: int, dtype, device) -> bool:
    """An internal ``[B]`` field already in shape, dtype and device (skips the checks of ``validate=False``)."""
    return isinstance(v, torch.Tensor) and v.shape == (b,) and v.dtype == dtype and v.device == device


def _get_photons(self) -> torch.Tensor:
    # the dense cube; a factored image builds it on first read (and keeps it): fast paths use project()
    p = self.__dict__.get("_photons")
    if p is None:
        f = self.__dict__.get("factors")
        if f is not None:
            p = f.dense()
            self.__dict__["_photons"] = p
            # (see SpectralImage.factors_hold_image; an inference tensor has no version counter)
            self.__dict__["_photons_built"] = (p, None if p.is_inference() else p._version)
    return p


def _set_photons(self, value) -> None:
    self.__dict__["_photons"] = value


@dataclasses.dataclass(eq=False, repr=False)
class SpectralImage:
    """Base of `Scene` and `OpticalImage`: photons [B, L, H, W] on a wavelength grid [L] (nm), dense or factored.

    Dense: ``photons [B, L, H, W]``. Factored: ``photons=None`` and ``factors`` a low-rank representation, e.g.
    :class:`SpectralFactors` (``maps [B, J, H, W]`` x ``spectra [B, J, L]``, see :meth:`from_factors`). A factored
    image answers ``project`` (and ``xyz``, luminance, ...) without forming the cube; reading ``.photons`` builds
    the dense cube once (:meth:`to_dense`), so code written for dense images keeps working.
    ``metadata`` is carried as it is (each copy a shallow copy of the dict) by ``[i]``, ``crop``, ``to`` and the
    other operations: per-item entries (e.g. :func:`~isettorch.scene.dead_leaves`' ``labels [B, H, W]``) are not
    sliced, cropped or concatenated with the image.
    """

    photons: torch.Tensor | None
    wavelengths_nm: torch.Tensor
    name: str = ""
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)
    factors: Any = None
    validate: dataclasses.InitVar[bool] = True

    # names of per-sample [B] fields in subclasses
    _batch_fields: ClassVar[tuple[str, ...]] = ()
    _units: ClassVar[str] = "photons"

    def __post_init__(self, validate: bool = True) -> None:
        p = self.__dict__.get("_photons")
        if self.factors is not None:
            if p is not None:
                raise ValueError("photons: expected None when factors are given (an image is dense or factored)")
            self._post_init_factored(validate)
            return
        if not isinstance(p, torch.Tensor):
            raise TypeError(f"photons: expected a torch.Tensor [B, L, H, W], got {type(p).__name__}")
        if p.dim() == 3:
            p = p.unsqueeze(0)
        check_rank(p, 4, "photons", "[B, L, H, W] (or [L, H, W])")
        if not p.is_floating_point():
            p = p.to(torch.get_default_dtype())
        if 0 in p.shape:
            raise ValueError(f"photons: expected a non-empty [B, L, H, W] image, got shape {tuple(p.shape)}")
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
                if not validate and _trusted_batch(v, p.shape[0], p.dtype, p.device):
                    continue
                setattr(self, f, batch_param(v, f, p.shape[0], dtype=p.dtype, device=p.device,
                                             positive=True))

    def _post_init_factored(self, validate: bool) -> None:
        f = self.factors
        w = self.wavelengths_nm
        if not validate and isinstance(w, torch.Tensor) and w.dtype == f.dtype and w.device == f.device \
                and w.dim() == 1 and w.numel() == getattr(f, "num_wavelengths", w.numel()):
            # (the length is checked even here: replace(wavelengths_nm=16 bands) on 31-band factors was kept)
            # trusted internal construction (replace, optics output): the grid was checked when first built
            for name in self._batch_fields:
                v = getattr(self, name)
                if v is not None and not _trusted_batch(v, self.batch_size, f.dtype, f.device):
                    setattr(self, name, batch_param(v, name, self.batch_size, dtype=f.dtype, device=f.device,
                                                    positive=True))
            return
        for attr in ("shape", "dtype", "device", "project", "dense", "select", "scale", "to", "detach"):
            if not hasattr(f, attr):
                raise TypeError(f"factors: expected a factored spectral image (e.g. SpectralFactors) with "
                                f"{attr!r}, got {type(f).__name__}")
        w = self.wavelengths_nm
        if not isinstance(w, torch.Tensor):
            w = torch.as_tensor(w, dtype=f.dtype)
        w = check_wavelengths(w.reshape(-1) if w.dim() == 0 else w).to(device=f.device, dtype=f.dtype)
        n_l = getattr(f, "num_wavelengths", w.numel())
        if w.numel() != n_l:
            raise ValueError(f"wavelengths_nm: expected {n_l} wavelengths to match the factors' spectra, "
                             f"got {w.numel()}")
        self.wavelengths_nm = w
        for name in self._batch_fields:
            v = getattr(self, name)
            if v is not None:
                if not validate and _trusted_batch(v, self.batch_size, f.dtype, f.device):
                    continue
                setattr(self, name, batch_param(v, name, self.batch_size, dtype=f.dtype, device=f.device,
                                                positive=True))

    @classmethod
    def from_factors(cls, maps: torch.Tensor, spectra: torch.Tensor, wavelengths_nm, *, terms=None,
                     **kwargs) -> SpectralImage:
        """A factored image ``sum_j maps[:, j] spectra[:, j, l]``: ``maps [B, J, H, W]`` (or ``[J, H, W]``),
        ``spectra [B, J, L]`` (or ``[J, L]``), both non-negative; ``terms`` (optional, B counts): item ``b``'s maps
        from ``terms[b]`` on are 0 (:class:`SpectralFactors`); other fields as for the dense constructor. The image
        has the maps' dtype and device: the spectra are cast to them (float32 maps round float64 spectra; the
        generators' float64 spectra beside float32 maps are meant so: the maps hold the pixels, the memory).

        Example:
            >>> from isettorch.scene import Scene
            >>> s = Scene.from_factors(torch.ones(1, 4, 4), torch.ones(1, 31), torch.arange(400., 701., 10.))
            >>> s.is_factored, tuple(s.photons.shape)
            (True, (1, 31, 4, 4))
        """
        validate = kwargs.get("validate", True)
        return cls(None, wavelengths_nm, factors=SpectralFactors(maps, spectra, validate=validate, terms=terms),
                   **kwargs)

    # --- shape and device -------------------------------------------------------------
    @property
    def is_factored(self) -> bool:
        """True when the image is held in a factored (low-rank or Fourier-domain) form (see ``factors``)."""
        return self.factors is not None

    @property
    def factors_hold_image(self) -> bool:
        """True when the factors are the image: factored, and its dense cube, if read, still the one built from
        them (not changed in place, not replaced). The fast paths (:meth:`project`, the optics' and the sensor's)
        then use the factors whether or not ``.photons`` was read: reading it took the dense path, whose rounding
        differs from the factors' (4e-8 relative in float32), and a Poisson draw with the same seed then came out
        different (0.02 V in a viewer session). A cube changed in place is the image: the dense path uses it. A
        cube read under ``torch.inference_mode`` has no version counter to tell: the dense path then, as before."""
        if self.factors is None:
            return False
        p = self.__dict__.get("_photons")
        if p is None:
            return True
        built = self.__dict__.get("_photons_built")
        return built is not None and built[0] is p and built[1] is not None and built[1] == p._version

    def _current(self) -> SpectralImage:
        """Self, or its dense form where the factors no longer hold the image (:attr:`factors_hold_image`: its cube
        was changed in place or replaced, and that cube is the image). The operations that build a new image
        (``to``, ``detach``, ``[i]``, ``crop``, ``resample_wavelengths``, ``set_mean_luminance``, ``Scene.cat``)
        start from it: they had rebuilt from the unchanged factors (``photons.mul_(2)`` then
        ``set_mean_luminance(100)`` gave 50 cd/m^2)."""
        return self.to_dense() if self.factors is not None and not self.factors_hold_image else self

    @property
    def maps(self) -> torch.Tensor:
        """The spatial maps ``[B, J, H, W]`` of a factored image (:class:`SpectralFactors`)."""
        if not isinstance(self.factors, SpectralFactors):
            raise AttributeError(f"maps: this {type(self).__name__} is not factored into maps x spectra")
        return self.factors.maps

    @property
    def spectra(self) -> torch.Tensor:
        """The spectra ``[B, J, L]`` of a factored image (:class:`SpectralFactors`)."""
        if not isinstance(self.factors, SpectralFactors):
            raise AttributeError(f"spectra: this {type(self).__name__} is not factored into maps x spectra")
        return self.factors.spectra

    def to_dense(self) -> SpectralImage:
        """The same image with a dense ``photons [B, L, H, W]`` (self when it is dense already)."""
        if self.factors is None:
            return self
        cached = self.__dict__.get("_photons")
        return self.replace(photons=self.factors.dense() if cached is None else cached)

    def project(self, weights: torch.Tensor) -> torch.Tensor:
        """``out[b, k] = sum_l photons[b, l] weights[l, k]`` ``[B, K, H, W]`` for ``weights [L, K]``, or per item
        ``weights [B, L, K]`` (``weights[b, l, k]``, e.g. a per-item sensor QE).

        A factored image never forms the ``[B, L, H, W]`` cube (J or K planes instead of L).
        """
        ok = isinstance(weights, torch.Tensor) and weights.dim() in (2, 3) and weights.shape[-2] == self.num_wavelengths
        if not ok or (weights.dim() == 3 and weights.shape[0] != self.batch_size):
            raise ValueError(f"weights: expected a [{self.num_wavelengths}, K] tensor (one row per wavelength) or "
                             f"[{self.batch_size}, {self.num_wavelengths}, K] per item, got "
                             f"{tuple(weights.shape) if isinstance(weights, torch.Tensor) else weights!r}")
        if self.factors_hold_image:
            return self.factors.project(weights.to(device=self.device, dtype=self.dtype))
        p = self.photons
        b, n_l, h, w = p.shape
        return (weights.to(p).transpose(-2, -1) @ p.reshape(b, n_l, h * w)).reshape(b, -1, h, w)

    def _spectral_map(self, fn) -> torch.Tensor:
        """``fn(x, dim)``: a functional linear along ``dim`` (L -> K), applied to the image ``[B, K, H, W]``."""
        f = self.factors
        if self.factors_hold_image:
            if hasattr(f, "spectral_map"):
                return f.spectral_map(fn)
            # a linear functional's weights: its response to each wavelength's delta
            eye = torch.eye(self.num_wavelengths, dtype=self.dtype, device=self.device)
            return self.project(fn(eye, -1))
        return fn(self.photons, 1)

    @property
    def batch_size(self) -> int:
        return self.factors.shape[0] if self.factors is not None else self.photons.shape[0]

    @property
    def num_wavelengths(self) -> int:
        return self.wavelengths_nm.numel()

    @property
    def height(self) -> int:
        return self.factors.shape[1] if self.factors is not None else self.photons.shape[2]

    @property
    def width(self) -> int:
        return self.factors.shape[2] if self.factors is not None else self.photons.shape[3]

    @property
    def device(self) -> torch.device:
        return self.factors.device if self.factors is not None else self.photons.device

    @property
    def dtype(self) -> torch.dtype:
        return self.factors.dtype if self.factors is not None else self.photons.dtype

    def replace(self, **changes) -> SpectralImage:
        """A copy with some fields changed (validation is skipped for internal, trusted changes).

        :meth:`Scene.replace <isettorch.scene.Scene.replace>` validates by default (a user's edit of a scene).
        Giving ``photons`` makes the copy dense, giving ``factors`` makes it factored; otherwise it stays as it is
        (a factored image is not densified).
        """
        changes.setdefault("validate", False)
        # a copy's own metadata dict (shallow: a key set on a crop had appeared on the original)
        changes.setdefault("metadata", dict(self.metadata))
        if "photons" in changes and "factors" not in changes:
            changes["factors"] = None
        elif "photons" not in changes:
            if "factors" in changes or self.factors is not None:
                changes["photons"] = None
        return dataclasses.replace(self, **changes)

    def _map_tensors(self, fn) -> dict[str, Any]:
        out = {}
        for f in dataclasses.fields(self):
            if not f.init or f.name == "factors":
                continue
            if f.name == "photons" and self.factors is not None:
                continue  # a factored image's dense cache (if read) is rebuilt from the moved factors on demand
            v = self.__dict__.get("_photons") if f.name == "photons" else getattr(self, f.name)
            if isinstance(v, torch.Tensor):
                out[f.name] = fn(v)
        return out

    def to(self, device=None, dtype=None) -> SpectralImage:
        """Move to a device and/or floating dtype (all tensors together)."""
        if dtype is not None and not (isinstance(dtype, torch.dtype) and dtype.is_floating_point):
            # (int32 had truncated a dense image's radiance, and was ignored for a factored one)
            raise ValueError(f"dtype: expected a floating torch dtype (e.g. torch.float64), got {dtype!r}")
        current = self._current()
        if current is not self:
            return current.to(device=device, dtype=dtype)
        changes = self._map_tensors(lambda t: t.to(device=device, dtype=dtype)
                                    if t.is_floating_point() else t.to(device=device))
        if self.factors is not None:
            changes["factors"] = self.factors.to(device=device, dtype=dtype)
        return self.replace(**changes, validate=False)

    def detach(self) -> SpectralImage:
        current = self._current()
        if current is not self:
            return current.detach()
        changes = self._map_tensors(lambda t: t.detach())
        if self.factors is not None:
            changes["factors"] = self.factors.detach()
        return self.replace(**changes, validate=False)

    def __getitem__(self, index) -> SpectralImage:
        """Select batch samples: ``img[0]``, ``img[1:3]``; the batch dimension is kept."""
        current = self._current()
        if current is not self:
            return current[index]
        if is_integer(index):
            b = self.batch_size
            if not -b <= index < b:  # (an empty slice failed in a reshape, or as 'photons: expected a non-empty')
                raise IndexError(f"index: {index} is out of range for a batch of {b}")
            index = int(index) % b
            index = slice(index, index + 1)
        if self.factors is not None:
            changes = {"factors": self.factors.select(index)}
            if changes["factors"].shape[0] == 0:  # (as a dense image's: a factored one had taken an empty batch)
                raise ValueError(f"index: {index!r} selects no items of the batch of {self.batch_size}")
        else:
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
        shape = (self.batch_size, self.num_wavelengths, self.height, self.width)
        form = f", factored {self.factors!r}" if self.factors is not None else ""
        return (
            f"{type(self).__name__}(name={self.name!r}, photons={shape} {self.dtype}{form} "
            f"on {self.device}, wavelengths={w[0].item():g}..{w[-1].item():g} nm ({w.numel()}), {extra})"
        )

    # --- spectral ----------------------------------------------------------------------
    def resample_wavelengths(self, wavelengths_nm) -> SpectralImage:
        """Linear interpolation onto another grid (0 outside the current range)."""
        current = self._current()
        if current is not self:
            return current.resample_wavelengths(wavelengths_nm)
        new = check_wavelengths(torch.as_tensor(wavelengths_nm)).to(self.device, self.dtype)
        if self.factors is not None and hasattr(self.factors, "resample"):
            changes = {"factors": self.factors.resample(self.wavelengths_nm, new), "wavelengths_nm": new}
        else:
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
        return self._spectral_map(lambda x, dim: spectral.luminance(x, self.wavelengths_nm, dim=dim))

    def xyz(self, observer: str = "1931") -> torch.Tensor:
        """Absolute CIE XYZ [B, 3, H, W] (Y in cd/m^2 for a scene, lux for an optical image)."""
        return self._spectral_map(lambda x, dim: spectral.xyz(x, self.wavelengths_nm, dim=dim, observer=observer))

    def _preview_white_y(self, xyz_img: torch.Tensor) -> torch.Tensor:
        return xyz_img[:, 1].flatten(1).amax(dim=1)

    def srgb(self) -> torch.Tensor:
        """Encoded sRGB preview [B, 3, H, W] in [0, 1]: XYZ scaled so the white (the illuminant for a
        scene that has one, else the brightest pixel) has Y = 1, IEC 61966-2-1 matrix and curve."""
        x = self.xyz()
        return xyz_to_srgb_preview(x, self._preview_white_y(x))

    def mean_spectrum(self, rows: slice | None = None, cols: slice | None = None) -> torch.Tensor:
        """Mean photons of a region [B, L] (rows/cols are slices; default the whole image)."""
        for name, s in (("rows", rows), ("cols", cols)):  # (row 0 was the whole image; an int dropped a dimension)
            if s is not None and not isinstance(s, slice):
                raise TypeError(f"{name}: expected a slice (e.g. slice(3, 4) for one row) or None, got "
                                f"{type(s).__name__} {s!r}")
        r = slice(None) if rows is None else rows
        c = slice(None) if cols is None else cols
        for name, s, n in (("rows", r, self.height), ("cols", c, self.width)):
            if len(range(*s.indices(n))) == 0:  # (the mean of no pixels was NaN)
                raise ValueError(f"{name}: {s} selects no pixels of {n}")
        f = self.factors
        if isinstance(f, SpectralFactors) and self.factors_hold_image:
            return (f.maps[:, :, r, c].mean(dim=(-2, -1))[:, :, None] * f.spectra).sum(dim=1)
        return self.photons[:, :, r, c].mean(dim=(-2, -1))

    def _check_window(self, top: int, left: int, height: int, width: int) -> None:
        _check_window(top, left, height, width, self.height, self.width)

    def _crop_photons(self, top: int, left: int, height: int, width: int) -> torch.Tensor:
        self._check_window(top, left, height, width)
        return self.photons[:, :, top:top + height, left:left + width]

    def _crop_changes(self, top: int, left: int, height: int, width: int) -> dict:
        """``photons`` (or ``factors``) of a window, for ``replace``."""
        f = self.factors
        if f is not None and hasattr(f, "crop") and self.factors_hold_image:  # (else its changed cube: _current)
            self._check_window(top, left, height, width)
            return {"factors": f.crop(top, left, height, width)}
        return {"photons": self._crop_photons(top, left, height, width)}

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



SpectralImage.photons = property(_get_photons, _set_photons, doc="Dense spectral cube ``[B, L, H, W]`` (built on "
                                 "first read for a factored image).")
