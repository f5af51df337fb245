"""A display model: three primaries' spectra, a transfer function (EOTF) and geometry (dpi, viewing distance).

Used to turn RGB images into spectral radiance (``scene.from_rgb``, ISETCam ``sceneFromFile`` with a display)
and, by the image processor, to render XYZ for a display (``isp.XYZToDisplay`` reads ``primaries_spd`` and
``wavelengths_nm``).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
from torch import nn

from .. import spectral
from .._checks import as_tensor, check_finite, check_rank, check_wavelengths
from ..image import srgb_decode, srgb_encode
from ..metrics.color import D65_XY, SRGB_PRIMARIES_XY, rgb_to_xyz_matrix  # IEC 61966-2-1 (CIE 1931 xy)
from ._common import check_float

__all__ = ["Display", "display_names", "SRGB_PRIMARIES_XY", "D65_XY"]

_METERS_PER_INCH = 0.0254


def srgb_eotf(encoded: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 decoding, encoded -> linear (:func:`isettorch.image.srgb_decode`)."""
    return srgb_decode(encoded)


def srgb_inverse_eotf(linear: torch.Tensor) -> torch.Tensor:
    """IEC 61966-2-1 encoding, linear -> encoded (:func:`isettorch.image.srgb_encode`: below 0 -> 0, no upper clip,
    as a display's inverse EOTF)."""
    return srgb_encode(linear, clip=False)


def flat_screen_hfov_deg(width_px: int, dpi: float, viewing_distance_m: float) -> float:
    """The angle (deg) ``width_px`` pixels at ``dpi`` subtend at ``viewing_distance_m`` on a flat screen,
    2 atan(w p / 2 d) with p = 0.0254 / dpi m."""
    return math.degrees(2 * math.atan(width_px * _METERS_PER_INCH / dpi / (2 * viewing_distance_m)))


def display_names() -> list[str]:
    """Names accepted by :meth:`Display.create`."""
    return ["crt", "lcd", "apple"]


@functools.cache
def _colour_primaries(key: str) -> tuple[np.ndarray, np.ndarray]:
    import colour

    m = colour.MSDS_DISPLAY_PRIMARIES[key]
    return np.asarray(m.wavelengths, float), np.asarray(m.values, float).T.copy()


@functools.cache
def _srgb_lcd_primaries() -> tuple[np.ndarray, np.ndarray]:
    """Primaries [3, L] on 380:1:780 nm with exactly the sRGB chromaticities and a D65 white (Y_white = 1).

    colour-science ships no sRGB display spectra, so each primary is a non-negative mixture of three Gaussian
    bands (460/12, 530/15, 620/10 nm centre/sigma, LCD-like) solved so its CIE 1931 XYZ equals the IEC
    61966-2-1 primary's; the mixtures are all non-negative (checked).
    """
    w = torch.arange(380.0, 781.0, dtype=torch.float64)
    bands = torch.stack([torch.exp(-0.5 * ((w - c) / s) ** 2) for c, s in ((460, 12), (530, 15), (620, 10))])
    cmf = spectral.cmfs(w, dtype=torch.float64)
    band_xyz = (bands @ cmf.T).T  # [XYZ, band] (1 nm grid, so the bin width is 1)
    target = rgb_to_xyz_matrix(SRGB_PRIMARIES_XY, D65_XY)  # [XYZ, RGB]
    mix = torch.linalg.solve(band_xyz, target)  # [band, RGB]
    if (mix < 0).any():  # pragma: no cover - guarded by the choice of bands
        raise RuntimeError("sRGB LCD primaries: negative band weights")
    spd = (bands.T @ mix).T  # [RGB, L]
    return w.numpy(), spd.numpy()


class Display(nn.Module):
    """A display: linear RGB (after its EOTF) -> spectral radiance ``sum_k rgb_k primaries_spd[k]``.

    Args:
        primaries_spd: [3, L] spectral radiance (W/sr/m^2/nm) of the R, G, B primaries at full drive.
        wavelengths_nm: grid [L] (nm).
        eotf: ``"srgb"`` (IEC 61966-2-1), ``"linear"``, or a gamma exponent (``linear = encoded ** gamma``).
        dpi: pixels per inch (sets the pixel pitch, 0.0254 / dpi m).
        viewing_distance_m: viewer distance (m), which sets a rendered image's field of view.
        max_luminance_cd_m2: if given, all primaries are scaled so the white (1, 1, 1) has this luminance.
        white_xy: if given, the primaries' gains are set so the white has this CIE 1931 chromaticity
            (luminance kept, or ``max_luminance_cd_m2``).

    ``xyz_matrix()`` [3, 3] maps linear RGB to absolute XYZ (cd/m^2); its columns are the primaries' XYZ
    (ISETCam ``displayGet(d, 'rgb2xyz')`` transposed). Source: ISETCam ``displayCreate`` / ``vDisplay``.

    Example:
        >>> d = Display.create("lcd")
        >>> round(d.max_luminance_cd_m2, 3), [round(v, 4) for v in d.white_xy.tolist()]
        (100.0, [0.3127, 0.329])
    """

    def __init__(self, primaries_spd, wavelengths_nm, eotf="srgb", *, dpi: float = 96.0,
                 viewing_distance_m: float = 0.5, max_luminance_cd_m2: float | None = None, white_xy=None,
                 name: str = "display"):
        super().__init__()
        w = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm", dtype=torch.float64), "wavelengths_nm")
        spd = as_tensor(primaries_spd, "primaries_spd", dtype=torch.float64)
        check_rank(spd, 2, "primaries_spd", "[3, L]")
        if spd.shape != (3, w.numel()):
            raise ValueError(f"primaries_spd: expected shape [3, {w.numel()}] (R, G, B x wavelengths), "
                             f"got {tuple(spd.shape)}")
        check_finite(spd, "primaries_spd")
        if (spd < 0).any() or not (spd.sum(dim=1) > 0).all():
            raise ValueError("primaries_spd: expected non-negative spectra, each with some power")
        if isinstance(eotf, str):
            if eotf not in ("srgb", "linear"):
                raise ValueError(f"eotf: expected 'srgb', 'linear' or a gamma exponent, got {eotf!r}")
            self.eotf_kind, self.gamma = eotf, None
        else:
            self.eotf_kind, self.gamma = "gamma", check_float(eotf, "eotf", low=0.0, low_open=True)
        self.dpi = check_float(dpi, "dpi", low=0.0, low_open=True)
        self.viewing_distance_m = check_float(viewing_distance_m, "viewing_distance_m", low=0.0, low_open=True)
        self.name = name
        self.register_buffer("wavelengths_nm", w.clone())
        self.register_buffer("primaries_spd", spd.clone())
        m = self.xyz_matrix().double()
        y_white = float(m[1].sum())
        if not y_white > 0 and (white_xy is not None or max_luminance_cd_m2 is not None):
            # (a ZeroDivisionError or a singular-matrix error)
            raise ValueError(f"primaries_spd: the primaries have no luminance on wavelengths_nm "
                             f"{float(w[0]):g}..{float(w[-1]):g} nm, so white_xy / max_luminance_cd_m2 cannot set it")
        if white_xy is not None:
            if isinstance(white_xy, (str, bytes)) or not hasattr(white_xy, "__len__") or len(white_xy) != 2:
                raise ValueError(f"white_xy: expected a chromaticity (x, y), got {white_xy!r}")
            xy = [check_float(v, f"white_xy[{i}]", low=0.0, high=1.0, low_open=True) for i, v in enumerate(white_xy)]
            if xy[0] + xy[1] >= 1:
                raise ValueError(f"white_xy: expected a chromaticity (x, y) with x + y < 1, got {white_xy}")
            target = torch.tensor([xy[0] / xy[1], 1.0, (1 - xy[0] - xy[1]) / xy[1]], dtype=torch.float64) * y_white
            # dependent primaries by their singular values, not by solve's exact-zero pivot: equal primaries whose
            # XYZ differ by round-off passed it and read 'outside the gamut' with gains of 1e34. Each primary's XYZ
            # is scaled to unit length first, so a dim primary is not read as a dependent one (its gain is free).
            norms = m.norm(dim=0)
            sv = torch.linalg.svdvals(m / torch.where(norms > 0, norms, torch.ones_like(norms)))
            if not float(sv[-1]) > 1e-10 * float(sv[0]):
                raise ValueError("white_xy: the primaries' XYZ are linearly dependent (primaries_spd), so no gains "
                                 "give a white point")
            gains = torch.linalg.solve(m, target)
            if (gains <= 0).any():
                raise ValueError(f"white_xy: {tuple(xy)} is outside the primaries' gamut (gains {gains.tolist()})")
            self.primaries_spd = self.primaries_spd * gains[:, None].to(self.primaries_spd)
        if max_luminance_cd_m2 is not None:
            target_y = check_float(max_luminance_cd_m2, "max_luminance_cd_m2", low=0.0, low_open=True)
            self.primaries_spd = self.primaries_spd * (target_y / self.max_luminance_cd_m2)

    # --- presets ---------------------------------------------------------------------------
    @classmethod
    def create(cls, name: str = "lcd", *, max_luminance_cd_m2: float = 100.0, **kwargs) -> Display:
        """A preset display, white scaled to ``max_luminance_cd_m2`` (default 100 cd/m^2; the presets' spectra are
        relative, so an absolute level is always set: None is refused).

        * ``"crt"``: 'Typical CRT Brainard 1997' primaries (colour-science), gamma 2.2.
        * ``"lcd"`` (or ``"srgb"``): sRGB-chromaticity LCD (primaries built from Gaussian bands to match IEC
          61966-2-1 xy exactly, D65 white), sRGB EOTF.
        * ``"apple"``: 'Apple Studio Display' primaries (colour-science), gamma 2.2. Not ISETCam's
          ``displayCreate('LCD-Apple')`` (101 samples, a measured 10-bit gamma table): its own primaries, a pure
          gamma.

        ISETCam's measured gamma tables are not modelled: the EOTF is sRGB, linear or a gamma exponent.

        Other keyword arguments (``dpi``, ``viewing_distance_m``, ``eotf``, ``white_xy``) go to the constructor.
        """
        if max_luminance_cd_m2 is None:  # (a 37,261 cd/m^2 CRT: colour-science's spectra are relative)
            raise ValueError("max_luminance_cd_m2: expected the white's luminance (cd/m^2); the presets' spectra are "
                             "relative, so they have no absolute level of their own")
        key = str(name).lower()
        if key == "crt":
            w, spd = _colour_primaries("Typical CRT Brainard 1997")
            kwargs.setdefault("eotf", 2.2)
        elif key in ("lcd", "srgb"):
            w, spd = _srgb_lcd_primaries()
            kwargs.setdefault("eotf", "srgb")
        elif key == "apple":
            w, spd = _colour_primaries("Apple Studio Display")
            kwargs.setdefault("eotf", 2.2)
        else:
            raise ValueError(f"name: unknown display {name!r}; expected one of {display_names()}")
        return cls(torch.from_numpy(spd), torch.from_numpy(w), max_luminance_cd_m2=max_luminance_cd_m2,
                   name=key, **kwargs)

    # --- colorimetry -----------------------------------------------------------------------
    def primaries_on(self, wavelengths_nm=None, *, sampling: str = "average", dtype=None, device=None
                     ) -> torch.Tensor:
        """Primaries [3, L'] (W/sr/m^2/nm) on another wavelength grid (0 outside the display's range).

        ``sampling="average"`` (default): each sample is the mean of the (piecewise-linear) primary over the
        sample's band (its integration weight, :func:`isettorch.spectral.wavelength_weights`), so the power in
        every band is kept; ``"point"``: linear interpolation at the sample (ISETCam ``interp1``), which misses
        narrow emission lines on coarse grids (CRT white on 400:10:700: luminance -1.9 % with point sampling,
        -0.06 % averaged). On the display's own grid the primaries are returned as they are.
        """
        if sampling not in ("average", "point"):  # (accepted on the display's own grid)
            raise ValueError(f"sampling: expected 'average' or 'point', got {sampling!r}")
        spd = self.primaries_spd
        if wavelengths_nm is not None:
            w = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm"), "wavelengths_nm")
            w = w.to(spd.device, torch.float64)
            src = self.wavelengths_nm.to(torch.float64)
            if not (w.numel() == src.numel() and torch.allclose(w, src, rtol=0, atol=1e-9)):
                if sampling == "point":
                    spd = spectral.resample(spd, src, w)
                else:
                    spd = spectral.band_average(spd, src, w)
        return spd.to(dtype=dtype or spd.dtype, device=device or spd.device)

    def xyz_matrix(self, wavelengths_nm=None, observer: str = "1931") -> torch.Tensor:
        """Linear RGB -> absolute XYZ (cd/m^2) [3, 3]: column k is the XYZ of primary k at full drive
        (``683 sum spd cmf dl``, CIE 015:2018), integrated on the display's grid or ``wavelengths_nm``."""
        w = self.wavelengths_nm if wavelengths_nm is None else as_tensor(wavelengths_nm, "wavelengths_nm")
        return spectral.xyz_of_energy(self.primaries_on(wavelengths_nm), w, dim=-1, observer=observer).T

    @property
    def white_xyz(self) -> torch.Tensor:
        """XYZ (cd/m^2) of RGB (1, 1, 1) [3]."""
        return self.xyz_matrix().sum(dim=1)

    @property
    def white_xy(self) -> torch.Tensor:
        """CIE 1931 chromaticity of the white [2]."""
        x = self.white_xyz
        return x[:2] / x.sum()

    @property
    def max_luminance_cd_m2(self) -> float:
        """Luminance of the white (cd/m^2)."""
        return float(self.xyz_matrix()[1].sum())

    @property
    def pixel_pitch_m(self) -> float:
        return _METERS_PER_INCH / self.dpi

    def hfov_deg(self, width_px: int) -> float:
        """Horizontal field of view (deg) of an image ``width_px`` pixels wide: 2 atan(w p / 2 d), a flat screen's
        (ISETCam's ``sceneFromFile`` takes w atan(p / d), the pixels' angle times their number: 58.2 against 53.9
        degrees for 1920 pixels at 96 dpi and 0.5 m, within 0.01 % for 64 pixels)."""
        return flat_screen_hfov_deg(width_px, self.dpi, self.viewing_distance_m)

    # --- transfer function ----------------------------------------------------------------
    def eotf(self, encoded: torch.Tensor) -> torch.Tensor:
        """Encoded drive values in [0, 1] -> linear primary intensities in [0, 1] (values outside are refused: each
        transfer function extended them its own way)."""
        _check_drive(encoded, "encoded", "drive values")
        return self._eotf(encoded)

    def _eotf(self, encoded: torch.Tensor) -> torch.Tensor:
        """:meth:`eotf` of values its caller checked (:func:`_check_rgb`: one pass over them, not two)."""
        if self.eotf_kind == "srgb":
            return srgb_eotf(encoded)
        if self.eotf_kind == "linear":
            return encoded
        if self.gamma < 1:  # d/dx x^g is infinite at 0 for g < 1 (inf gradients at black), as inverse_eotf's
            return encoded.clamp_min(torch.finfo(encoded.dtype).tiny) ** self.gamma
        return encoded.clamp_min(0) ** self.gamma

    def inverse_eotf(self, linear: torch.Tensor) -> torch.Tensor:
        """Linear intensities in [0, 1] -> encoded drive values (for rendering to this display)."""
        if self.eotf_kind == "srgb":
            return srgb_inverse_eotf(linear)
        if self.eotf_kind == "linear":
            return linear
        # d/dx x^(1/g) is infinite at 0; clamp to the smallest normal number so gradients stay finite.
        return linear.clamp_min(torch.finfo(linear.dtype).tiny) ** (1 / self.gamma)

    # --- rendering --------------------------------------------------------------------------
    def linear_rgb_to_radiance(self, linear: torch.Tensor, wavelengths_nm=None, *, units: str = "photons"
                               ) -> torch.Tensor:
        """Linear RGB [B, 3, H, W] -> spectral radiance [B, L, H, W] (photons/s/sr/m^2/nm, or W/sr/m^2/nm
        with ``units="energy"``) on the display's grid or ``wavelengths_nm``."""
        _check_rgb(linear, "linear")
        w = self.wavelengths_nm if wavelengths_nm is None else check_wavelengths(
            as_tensor(wavelengths_nm, "wavelengths_nm"), "wavelengths_nm")
        spd = self.primaries_on(w, dtype=linear.dtype, device=linear.device)
        energy = torch.einsum("kl,bkhw->blhw", spd, linear)
        if units == "energy":
            return energy
        if units != "photons":
            raise ValueError(f"units: expected 'photons' or 'energy', got {units!r}")
        return spectral.energy_to_photons(energy, w.to(linear.device, linear.dtype), dim=1)

    def rgb_to_radiance(self, rgb: torch.Tensor, wavelengths_nm=None, *, units: str = "photons") -> torch.Tensor:
        """Encoded RGB [B, 3, H, W] in [0, 1] -> spectral radiance [B, L, H, W] (see linear_rgb_to_radiance)."""
        _check_rgb(rgb, "rgb", encoded=True)
        return self.linear_rgb_to_radiance(self._eotf(rgb), wavelengths_nm, units=units)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.rgb_to_radiance(rgb)

    def extra_repr(self) -> str:
        eotf = self.eotf_kind if self.gamma is None else f"gamma {self.gamma:g}"
        return (f"name={self.name!r}, eotf={eotf}, dpi={self.dpi:g}, viewing_distance_m={self.viewing_distance_m:g}, "
                f"max_luminance_cd_m2={self.max_luminance_cd_m2:.4g}")


def _check_rgb(rgb, name: str, encoded: bool = False) -> None:
    if not isinstance(rgb, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor [B, 3, H, W], got {type(rgb).__name__}")
    if rgb.dim() != 4 or rgb.shape[1] != 3:
        raise ValueError(f"{name}: expected shape [B, 3, H, W], got {tuple(rgb.shape)}")
    if rgb.dtype not in (torch.float32, torch.float64):  # (float16 radiance underflowed to 0 photons)
        raise TypeError(f"{name}: expected a float32 or float64 tensor with values in [0, 1], got {rgb.dtype}")
    if encoded:
        _check_drive(rgb, name)
        return
    if rgb.numel() == 0:  # (an empty batch failed in min())
        raise ValueError(f"{name}: expected a non-empty image, got shape {tuple(rgb.shape)}")
    check_finite(rgb.detach(), name)
    lo = rgb.detach().min().item()
    if lo < 0:
        raise ValueError(f"{name}: expected non-negative linear values, got minimum {lo:.6g}")


def _check_drive(x: torch.Tensor, name: str, what: str = "encoded values") -> None:
    """Encoded drive values: finite and in [0, 1], else a ValueError naming ``name`` (``what`` they are called)."""
    if x.numel() == 0:  # (an empty batch failed in min())
        raise ValueError(f"{name}: expected a non-empty image, got shape {tuple(x.shape)}")
    check_finite(x.detach(), name)
    lo, hi = x.detach().min().item(), x.detach().max().item()
    if lo < 0 or hi > 1:
        raise ValueError(f"{name}: expected {what} in [0, 1], got range [{lo:.6g}, {hi:.6g}]")
