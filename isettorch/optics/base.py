"""`ShiftInvariantLens`: the part every shift-invariant optics shares.

scene radiance -> camera equation x transmittance -> relative illumination -> OTF blur (FFT) -> OpticalImage.
Subclasses provide the OTF (:meth:`otf`), how far the PSF reaches (:meth:`psf_margin_m`) and, optionally, a
test for a negligible blur (:meth:`blur_negligible`).

**The optics contract** (what any optics module, shift-invariant or not, implements for `Camera`):

* ``forward(scene, crop=None) -> OpticalImage`` for a dense **and** a factored scene (``scene.is_factored``:
  ``scene.factors`` is a :class:`~isettorch.image.SpectralFactors`, radiance = sum_j maps_j(x) spectra_j(l)).
  The valid minimum for a new optics (e.g. a ray-traced, shift-variant lens) is ``scene = scene.to_dense()``
  first; an optics that is linear per wavelength and shift-invariant does better by transforming the J maps
  once and returning a factored optical image (``OpticalImage(None, ..., factors=...)``, whose ``factors``
  implement ``project(weights [L, K]) -> [B, K, H, W]``, ``dense()``, ``select``, ``scale``, ``crop``, ``to``,
  ``detach``; see :class:`~isettorch.optics.optical_image.FourierFactors`): the sensor then only asks for its K
  projected planes.
* optionally ``plan(scene) -> dict`` (``full_shape``, ``pad``, ``sample_spacing_m``, ``image_distance_m``,
  ``margin``) and ``crop=(top, left, height, width)``, so `Camera` computes only the sensor's window.
  Neither may read ``scene.photons`` of a factored scene (it would build the cube): use ``scene.height``,
  ``scene.width``, ``scene.batch_size``, ``scene.dtype``, ``scene.device``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .. import spectral
from .._autograd import full_precision, records_grad
from .._cache import BoundedCache
from .._checks import as_tensor, batch_param, check_bool, check_nonnegative, check_wavelengths, is_real, warn_caller
from ..image import SpectralFactors, angle_for_extent
from ..scene.scene import Scene
from . import geometry
from .blur import PAD_MODES, blur_fft, extend, fft_buffer, fft_frequencies, full_padding
from .optical_image import FourierFactors, OpticalImage, _scratch, stack_rows

__all__ = ["ShiftInvariantLens"]

_CACHE_SIZE = 8

#: The smallest f-number of a lens in air: N = 1 / (2 NA) for an aplanatic lens (Abbe sine condition), with the
#: numerical aperture NA = n sin(theta) <= 1 in air (n = 1), so N >= 0.5 (E. Hecht, Optics, 5th ed., Pearson 2017,
#: ch. 5: stops, the f-number and the numerical aperture).
MIN_F_NUMBER = 0.5


def per_item_products(device: torch.device) -> bool:
    """Whether the factored optics work item by item on ``device`` (each item's cached OTF row, only its used
    terms): on a CPU, where B small products cost less than one padded batched product; not on an accelerator,
    where one batched launch beats B small ones. (A function, so a test can run the batched path on a CPU.)"""
    return device.type == "cpu"


def _check_crop(crop) -> None:
    if crop is None:
        return
    if not (isinstance(crop, (tuple, list)) and len(crop) == 4 and all(isinstance(v, int) for v in crop)):
        raise ValueError(f"crop: expected None or (top, left, height, width) ints in optical-image samples, "
                         f"got {crop!r}")


def check_not_detached(value, name: str, how: str) -> None:
    """ValueError naming ``name`` when ``value`` is a tensor that requires grad but an optics module copies it as a
    constant (no gradient would reach it); ``how`` says what to do instead (e.g. the module's learn_* option)."""
    if isinstance(value, torch.Tensor) and value.requires_grad:
        raise ValueError(f"{name}: got a tensor that requires grad, but the optics copy it as a constant (no "
                         f"gradient would reach it); {how}")


class ShiftInvariantLens(nn.Module):
    """Base class of the shift-invariant optics (thin lens, camera equation, relative illumination, OTF blur).

    Args:
        f_number: f-number ``N`` (scalar or ``[B]``), an ``nn.Parameter`` when ``learn_f_number``.
        focal_length_m: focal length (m), scalar or ``[B]``.
        transmittance: lens transmittance T(lambda): None (1), a scalar, or ``[K]`` values on
            ``transmittance_wavelengths_nm`` (resampled linearly to the scene grid, 0 outside) or, without a
            grid, ``[L]`` values on the scene's own grid.
        relative_illumination: ``'cos4th'`` (default, cos^4 law at the image distance), ``'isetcam'``
            (ISETCam's finite-aperture ``cos4th.m`` formula, with the thin-lens magnification) or None.
        camera_equation: ``'isetcam'`` (``pi / (1 + 4 N^2 (1 + |m|)^2)``) or ``'paraxial'``
            (``pi / (4 N^2 (1 + |m|)^2)``); see :func:`~isettorch.optics.geometry.camera_equation_factor`.
        pad_mode: ``'zero'``, ``'mean'``, ``'edge'`` or a number: what lies beyond the scene's edges. A number is
            a radiance (the scene's units), imaged like the scene's: camera equation and transmittance, with the
            relative illumination held at the edges' value beyond them.
        psf_tolerance: fraction of the line-spread energy allowed beyond the padding margin (sets how far
            the image is padded; it bounds both the wrap-around and, for ``crop=``, the missed light). A batch is
            padded by the margin its widest PSF needs, so an item rendered beside one of a larger f-number or a
            finer sampling differs from its render alone within this tolerance (2.3e-4 of the maximum for f/2
            beside f/11); items of one geometry, or a fixed ``margin``, render bitwise as they do alone.
        blur_skip_tolerance: the blur is skipped when the OTF differs from 1 by less than this at every
            frequency of the grid (only where the optics can tell cheaply, e.g. diffraction-limited).
        margin: force the padding margin (samples per side) instead of deriving it from ``psf_tolerance``.
        max_margin_factor: cap of the derived margin, in units of the scene's larger side.
        learn_f_number: make ``f_number`` a trainable ``nn.Parameter`` (it is a parameter either way, frozen without
            this flag: ``module.requires_grad_(True)`` unfreezes it too).
    """

    def __init__(self, f_number=4.0, focal_length_m=3.862755099e-3, transmittance=None,
                 transmittance_wavelengths_nm=None, *, relative_illumination: str | None = "cos4th",
                 camera_equation: str = "isetcam", pad_mode="zero", psf_tolerance: float = 1e-3,
                 blur_skip_tolerance: float = 1e-3, margin: int | None = None, max_margin_factor: float = 2.0,
                 learn_f_number: bool = False, dtype=torch.float64) -> None:
        super().__init__()
        check_bool(learn_f_number, "learn_f_number")
        if isinstance(f_number, bool):
            raise TypeError(f"f_number: expected a number or [B] tensor, got {f_number!r}")
        # values are copied (detached): a tensor that requires grad would silently lose its gradient
        for name, value, how in (("f_number", f_number, "pass learn_f_number=True (the module's own parameter)"),
                                 ("focal_length_m", focal_length_m, "the focal length is a fixed property here"),
                                 ("transmittance", transmittance, "the transmittance is a fixed property here")):
            if not (name == "f_number" and learn_f_number):
                check_not_detached(value, name, how)
        n = as_tensor(f_number, "f_number", dtype=dtype).detach().clone()
        if n.dim() > 1 or not torch.isfinite(n).all() or (n < MIN_F_NUMBER).any():
            raise ValueError(f"f_number: expected a finite scalar or [B] tensor >= {MIN_F_NUMBER} (the fastest lens in "
                             f"air, N = 1 / (2 NA) with NA <= 1), got {n.tolist()}")
        self.f_number = nn.Parameter(n, requires_grad=learn_f_number)
        fl = as_tensor(focal_length_m, "focal_length_m", dtype=dtype).detach().clone()
        if fl.dim() > 1 or not torch.isfinite(fl).all() or (fl <= 0).any():
            raise ValueError(f"focal_length_m: expected a positive scalar or [B] tensor, got {fl.tolist()}")
        self.register_buffer("focal_length_m", fl)
        if transmittance is None:
            self.transmittance = None
        else:
            if isinstance(transmittance, bool):
                raise TypeError(f"transmittance: expected a number or values in [0, 1], got {transmittance!r}")
            t = as_tensor(transmittance, "transmittance", dtype=dtype).detach().clone().reshape(-1)
            check_transmittance(t)
            self.register_buffer("transmittance", t)
        if transmittance_wavelengths_nm is None:
            self.transmittance_wavelengths_nm = None
        else:
            tw = check_wavelengths(as_tensor(transmittance_wavelengths_nm, "transmittance_wavelengths_nm",
                                             dtype=dtype), "transmittance_wavelengths_nm")
            n_t = 0 if self.transmittance is None else self.transmittance.numel()
            if tw.numel() != n_t:
                raise ValueError(f"transmittance_wavelengths_nm: expected {n_t} wavelengths (one per "
                                 f"transmittance value), got {tw.numel()}")
            self.register_buffer("transmittance_wavelengths_nm", tw)
        if relative_illumination not in (None, "none", "cos4th", "isetcam"):
            raise ValueError(f"relative_illumination: expected None, 'cos4th' or 'isetcam', "
                             f"got {relative_illumination!r}")
        if camera_equation not in ("isetcam", "paraxial"):
            raise ValueError(f"camera_equation: expected 'isetcam' or 'paraxial', got {camera_equation!r}")
        if not (pad_mode in PAD_MODES or (isinstance(pad_mode, (int, float)) and not isinstance(pad_mode, bool))):
            raise ValueError(f"pad_mode: expected one of {PAD_MODES} or a number, got {pad_mode!r}")
        if not isinstance(pad_mode, str) and not (math.isfinite(pad_mode) and pad_mode >= 0):
            # a number is the value (in the image's units) beyond the scene's edges: a radiance, finite and >= 0
            raise ValueError(f"pad_mode: expected one of {PAD_MODES} or a finite non-negative number (the radiance "
                             f"beyond the scene's edges), got {pad_mode!r}")
        if not (is_real(psf_tolerance) and 0 < psf_tolerance < 1):  # (a string raised a bare TypeError)
            raise ValueError(f"psf_tolerance: expected a number in (0, 1), got {psf_tolerance!r}")
        if not (is_real(blur_skip_tolerance) and 0 <= blur_skip_tolerance < 1):
            raise ValueError(f"blur_skip_tolerance: expected a number in [0, 1), got {blur_skip_tolerance!r}")
        if margin is not None and (not isinstance(margin, int) or isinstance(margin, bool) or margin < 0):
            raise ValueError(f"margin: expected None or a non-negative int, got {margin!r}")
        if not (isinstance(max_margin_factor, (int, float)) and not isinstance(max_margin_factor, bool)
                and math.isfinite(max_margin_factor) and max_margin_factor > 0):
            raise ValueError(f"max_margin_factor: expected a positive finite number (the margin's cap in units of the "
                             f"scene's larger side), got {max_margin_factor!r}")
        self.relative_illumination = relative_illumination
        self.camera_equation = camera_equation
        self.pad_mode = pad_mode
        self.psf_tolerance = float(psf_tolerance)
        self.blur_skip_tolerance = float(blur_skip_tolerance)
        self.margin = margin
        self.max_margin_factor = float(max_margin_factor)
        self._otf_cache = BoundedCache(_CACHE_SIZE)
        self._otf_rows = BoundedCache(8 * _CACHE_SIZE)
        self._interleaved_cache = BoundedCache(_CACHE_SIZE)
        self._geometry_cache = BoundedCache(4 * _CACHE_SIZE)

    # --- to override --------------------------------------------------------------------------------
    # True when item b of :meth:`otf` depends only on ``fy[b], fx[b], f_number[b]`` and the module's fixed settings
    # (no other per-item state), so OTF rows may be cached per item (:meth:`_otf_by_item`)
    otf_rows_independent = False

    def otf(self, fy: torch.Tensor, fx: torch.Tensor, wavelengths_nm: torch.Tensor, f_number: torch.Tensor,
            ) -> torch.Tensor:
        """OTF ``[B, L, My, Mx]`` at frequencies ``fy [B, My]``, ``fx [B, Mx]`` (cycles/m), DC = 1."""
        raise NotImplementedError

    def psf_margin_m(self, wavelengths_nm: torch.Tensor, f_number: torch.Tensor) -> torch.Tensor:
        """How far (m) the PSF reaches at ``psf_tolerance``, ``[B]``."""
        raise NotImplementedError

    def psf_core_m(self, wavelengths_nm: torch.Tensor, f_number: torch.Tensor) -> torch.Tensor | float:
        """How far (m) the PSF's compact part reaches (a geometric blur disc, a measured kernel), within which it
        holds a share of its light far above ``psf_tolerance``: a padding margin short of it wraps that light around.
        0 for a PSF of a diffraction tail alone (its light beyond a capped margin falls as 1 / distance)."""
        return 0.0

    def psf_extent_m(self, wavelengths_nm: torch.Tensor, f_number: torch.Tensor) -> tuple:
        """``(psf_margin_m, psf_core_m)`` in one call (a subclass whose margin contains its core computes the core
        once)."""
        return self.psf_margin_m(wavelengths_nm, f_number), self.psf_core_m(wavelengths_nm, f_number)

    def blur_negligible(self, dx: torch.Tensor, wavelengths_nm: torch.Tensor, f_number: torch.Tensor) -> bool:
        return False

    def _otf_key(self) -> tuple:
        return ()

    # True when the blur is the pupil's (diffraction, aberrations given on the pupil): :meth:`otf`,
    # :meth:`psf_margin_m` and :meth:`blur_negligible` then describe the lens focused at infinity, and a lens
    # focused at a finite distance has that PSF magnified by d_i / f (the converging wave's radius is the exit
    # pupil-to-image distance, d_i for a thin lens, not f: the incoherent cutoff is D / (lambda d_i) =
    # 1 / (lambda N (1 + |m|)), the working f-number; Goodman, Introduction to Fourier Optics, 3rd ed., 6.3.2,
    # the cutoff 2 w / (lambda z_i)). False for a PSF given on the image plane as it is (a measured PSF).
    blur_at_image_distance = False

    def _blur_spacing(self, dx: torch.Tensor, f: torch.Tensor, d_i: torch.Tensor) -> torch.Tensor:
        """The sample spacing at which the infinity-focused blur (:meth:`otf`, :meth:`psf_margin_m`,
        :meth:`blur_negligible`) is evaluated: ``dx f / d_i`` when :attr:`blur_at_image_distance` (the OTF at
        frequency ``nu`` of a lens focused at ``d_i`` is the infinity OTF at ``nu d_i / f``), else ``dx``."""
        return dx * (f / d_i) if self.blur_at_image_distance else dx

    # --- shared ---------------------------------------------------------------------------------------
    def batch_f_number(self, batch: int, dtype, device) -> torch.Tensor:
        n = batch_param(self.f_number.to(dtype=dtype, device=device), "f_number", batch, dtype=dtype, device=device,
                        positive=True)
        if bool((n.detach() < MIN_F_NUMBER).any()):
            # a learned f-number an optimiser step took below the physical limit the constructor enforces: an error,
            # not a lens faster than any lens in air (keep it in range, e.g. clamp it after each step)
            raise ValueError(f"f_number: expected >= {MIN_F_NUMBER} (the fastest lens in air), got "
                             f"{n.detach().tolist()} (a learned f-number left the physical range)")
        return n

    def batch_focal_length(self, batch: int, dtype, device) -> torch.Tensor:
        return batch_param(self.focal_length_m, "focal_length_m", batch, dtype=dtype, device=device, positive=True)

    def transmittance_on(self, wavelengths_nm: torch.Tensor) -> torch.Tensor | None:
        """Lens transmittance on a wavelength grid ``[L]`` (None when it is 1)."""
        t = self.transmittance
        if t is None:
            return None
        t = t.to(wavelengths_nm.dtype)
        if t.numel() == 1:
            return t.expand(wavelengths_nm.numel())
        if self.transmittance_wavelengths_nm is None:
            if t.numel() != wavelengths_nm.numel():
                raise ValueError(f"transmittance: expected {wavelengths_nm.numel()} values on the scene's grid "
                                 f"(or give transmittance_wavelengths_nm), got {t.numel()}")
            return t
        return spectral.resample(t, self.transmittance_wavelengths_nm, wavelengths_nm)

    def _requires_grad(self) -> bool:
        return records_grad(self.f_number, self)

    def _otf_fn(self, wavelengths_nm, f_number, dx):
        def fn(fy, fx):
            # the optics' parameters, or the scene's field of view or distance through the sample spacing (a cached
            # OTF dropped the blur's term of d/d hfov_deg: -2.4e-4 for +0.49)
            if self._requires_grad() or records_grad(dx, fy, fx):
                return self.otf(fy, fx, wavelengths_nm, f_number)
            key = self._otf_key_for(fy, fx, wavelengths_nm, f_number, dx)
            hit = self._otf_cache.get(key)
            if hit is None:
                hit = self._otf_by_item(fy, fx, wavelengths_nm, f_number, dx, key)
                self._otf_cache[key] = hit  # (bounded in entries and bytes)
            return hit
        return fn

    def _otf_by_item(self, fy, fx, wavelengths_nm, f_number, dx, key) -> torch.Tensor:
        """The OTF ``[B, L, My, Mx']`` of a batch whose items have their own f-number and spacing ``[B]``, built
        from per-item rows cached by (f-number, spacing): a training stream draws each batch's f-numbers from a
        few stops, so a new combination of known items costs a copy, not an OTF evaluation."""
        rows = self._item_otf_rows(fy, fx, wavelengths_nm, f_number, dx, key)
        if rows is None:
            return self.otf(fy, fx, wavelengths_nm, f_number).detach()
        out = stack_rows(rows)  # never written to: the cached row itself
        if out.is_complex():
            return out
        plain = out[..., 0]  # a view: the interleaved batch is registered as its interleaved copy
        self._interleaved_cache[id(plain)] = (plain, out)
        return plain

    def _otf_key_for(self, fy, fx, wavelengths_nm, f_number, dx) -> tuple:
        # the buffer's width, not the rFFT's Mx // 2 + 1 columns: widths 2k and 2k + 1 have as many columns on other
        # frequencies (1 / (Mx dx) apart), and shared an OTF (4 % of the peak off for 24 and 25)
        n = fx.shape[-1]
        even = n > 1 and abs(float(fx.reshape(-1, n)[0, -1]) * float(dx.reshape(-1)[0]) - 0.5) < 1e-6
        width = 2 * (n - 1) + (0 if even else 1)
        return (fy.shape[-1], width, tuple(dx.tolist()), tuple(wavelengths_nm.tolist()),
                tuple(f_number.tolist()), self._otf_key(), fy.dtype, str(fy.device))

    def _item_otf_rows(self, fy, fx, wavelengths_nm, f_number, dx, key=None) -> list | None:
        """The OTF of each item as its cached row ``[1, L, My, Mx'(, 2)]`` (a real OTF kept interleaved: the same
        value for the real and imaginary parts), evaluated once per (f-number, spacing, grid); None where rows do
        not apply (an OTF that is not per item, or one that needs a gradient)."""
        n = f_number.reshape(-1)
        # one item goes through the rows too: a stream builds a new optics module per group, sharing the rows, so
        # a one-item group would otherwise evaluate its OTF again (measured 9 of 28 ms per one-item group)
        if (not self.otf_rows_independent or dx.numel() != n.numel() or self._requires_grad()
                or records_grad(dx, fy, fx)):
            return None
        key = self._otf_key_for(fy, fx, wavelengths_nm, n, dx) if key is None else key
        rows = []
        for b, (n_b, dx_b) in enumerate(zip(key[4], key[2])):
            row_key = (key[0], key[1], dx_b, key[3], n_b, *key[5:])
            row = self._otf_rows.get(row_key)
            if row is None:
                row = self.otf(fy[b:b + 1], fx[b:b + 1], wavelengths_nm, n[b:b + 1]).detach()
                if not row.is_complex():  # kept interleaved (see _interleaved): the batch is one copy of rows
                    row = row[..., None].expand(*row.shape, 2).contiguous()
                self._otf_rows[row_key] = row  # (bounded in entries and bytes)
            rows.append(row)
        return rows

    def clear_cache(self) -> None:
        self._otf_cache.clear()
        self._otf_rows.clear()
        self._interleaved_cache.clear()
        self._geometry_cache.clear()

    def margin_samples(self, scene_shape: tuple[int, int], dx: torch.Tensor, wavelengths_nm, f_number) -> int:
        if self.margin is not None:
            return self.margin
        m, core = self.psf_extent_m(wavelengths_nm, f_number)
        samples = int(math.ceil(float((m.detach() / dx.detach()).max())))
        cap = int(math.ceil(self.max_margin_factor * max(scene_shape)))
        core = torch.as_tensor(core).detach().to(dx.device, dx.dtype)
        core_samples = int(math.ceil(float((core / dx.detach()).max())))
        if samples > 10 * cap or core_samples > cap:
            # The PSF reaches far beyond the capped padding: the FFT's circular convolution folds the light beyond
            # the margin back onto the image (for diffraction, whose line-spread tail falls as 1 / distance, about
            # psf_tolerance x samples / cap of it: over 10x the tolerance here; for a compact blur, e.g. a defocus
            # disc, the share of its light beyond the cap: 26 % more light in a point's window for a 1 um defocus
            # at f/2 whose disc reaches 5.6x the cap). Say so rather than render it.
            warn_caller(
                f"optics: the PSF reaches {samples} samples beyond the scene at psf_tolerance {self.psf_tolerance:g} "
                f"(sample spacing {float(dx.detach().min()) * 1e6:.4g} um), but the padding is capped at {cap} "
                f"(max_margin_factor {self.max_margin_factor:g} x the scene's {max(scene_shape)} samples): light "
                "beyond the margin wraps around onto the image. The blur is larger than the scene: sample the scene "
                "more coarsely (a wider field of view), or raise max_margin_factor / give margin.")
        return min(samples, cap)

    def _geometry(self, scene: Scene):
        b, w = scene.batch_size, scene.width
        dt, dev = scene.dtype, scene.device
        n = self.batch_f_number(b, dt, dev)
        f = self.batch_focal_length(b, dt, dev)
        d_i = geometry.image_distance(f, scene.distance_m)
        dx = geometry.image_sample_spacing(scene.hfov_deg, w, d_i)
        return n, f, d_i, dx

    def plan(self, scene: Scene) -> dict:
        """The full optical image's geometry, without computing it (for choosing a ``crop`` window).

        Returns a dict with ``full_shape`` (H2, W2), ``pad`` (rows, cols per side), ``sample_spacing_m`` ``[B]``,
        ``image_distance_m`` ``[B]`` and ``margin`` (samples the PSF reaches at ``psf_tolerance``; a window
        needs this much of the scene beyond it, which ``forward`` takes care of).
        """
        h, w = scene.height, scene.width
        (_, _, _, n, f, d_i, dx), derived = self._geometry_entry(scene)
        hit = derived.get("plan")
        if hit is not None:
            return dict(hit)
        wave = scene.wavelengths_nm
        dxb = self._blur_spacing(dx, f, d_i)
        if self._negligible(derived, dxb, wave, n):
            margin = 0 if self.margin is None else self.margin
            pr = pc = margin
        else:
            margin = self._margin(derived, (h, w), dxb, wave, n)
            pr, pc = full_padding(h, margin), full_padding(w, margin)
        out = derived["plan"] = {"full_shape": (h + 2 * pr, w + 2 * pc), "pad": (pr, pc), "sample_spacing_m": dx,
                                 "image_distance_m": d_i, "margin": margin}
        return dict(out)

    @full_precision
    def forward(self, scene: Scene, crop: tuple[int, int, int, int] | None = None) -> OpticalImage:
        """Scene -> optical image.

        Args:
            scene: `Scene` with photons ``(B, L, H, W)``.
            crop: optional window ``(top, left, height, width)`` in samples of the full (padded) optical
                image: only that window is computed (with the sources within the PSF margin of it).

        Returns:
            `OpticalImage` ``(B, L, H + 2 pad_rows, W + 2 pad_cols)`` (or the window), photons/s/m^2/nm, on a grid
            centred on the optical axis. For a window, ``metadata['window']`` is its ``(top, left)`` in the
            full image and ``metadata['full_shape']`` / ``metadata['full_pad']`` the full size and padding.
        """
        if not isinstance(scene, Scene):
            raise TypeError(f"scene: expected a Scene, got {type(scene).__name__}")
        _check_crop(crop)
        if scene.factors_hold_image and self._factored_ok(scene):
            return self._forward_factored(scene, crop)
        # camera equation (ISETCam oiCalculateIrradiance), transmittance, relative illumination
        k, t, ri, n, f, d_i, dx = self._spatial_factors(scene)
        irr = scene.photons * k.reshape(-1, 1, 1, 1)
        if t is not None:
            irr = irr * t.to(device=irr.device).reshape(1, -1, 1, 1)
        if ri is not None:
            irr = irr * ri
        fill = None
        if not isinstance(self.pad_mode, str):
            # a number is a radiance beyond the scene's edges: imaged like the scene's (it was used as an irradiance,
            # 1 / k of it: a uniform scene padded with its own radiance came out 20x brighter beyond it at f/4)
            fill = irr.new_full((1, 1, 1, 1), float(self.pad_mode)) * k.reshape(-1, 1, 1, 1).to(irr.dtype)
            if t is not None:
                fill = fill * t.to(device=irr.device, dtype=irr.dtype).reshape(1, -1, 1, 1)
            if ri is not None:
                fill = fill * ri
        return self._blur_to_oi(irr, scene.wavelengths_nm, dx, n, f, d_i, crop, name=scene.name, fill=fill)

    def _factored_ok(self, scene: Scene) -> bool:
        """The factored path needs maps x spectra and a pad mode that is linear in the image."""
        return isinstance(scene.factors, SpectralFactors) and self.pad_mode in PAD_MODES

    def _spatial_factors(self, scene: Scene):
        """``(k [B], T [L] or None, ri [B, 1, H, W] or None, n, f, d_i, dx)``: the camera-equation factor (ISETCam
        oiCalculateIrradiance), transmittance and relative illumination that turn radiance into irradiance.

        Cached (a few entries) per scene geometry when no gradient is needed: they depend only on the optics'
        settings, the scene's size, FOV, distance and wavelength grid (a dataset of a few cameras repeats them)."""
        return self._geometry_entry(scene)[0]

    def _geometry_entry(self, scene: Scene) -> tuple[tuple, dict]:
        """``(spatial factors, derived)``: :meth:`_spatial_factors` and a dict memoising what else depends only on
        the same key (the plan, the blur test, the margin, the FFT frequencies and OTF of a buffer size, the
        optical image's FOV), so a camera call on a repeated geometry does no per-call tensor work for them.
        ``derived`` is a fresh dict (nothing memoised) when a gradient is needed."""
        if self._requires_grad() or scene.hfov_deg.requires_grad or scene.distance_m.requires_grad:
            return self._compute_spatial_factors(scene), {}
        # the optics' own values (not only their version counters: a replaced parameter starts a new counter)
        t, tw = self.transmittance, self.transmittance_wavelengths_nm
        key = (scene.height, scene.width, tuple(scene.hfov_deg.tolist()), tuple(scene.distance_m.tolist()),
               tuple(scene.wavelengths_nm.tolist()), scene.dtype, str(scene.device),
               tuple(self.f_number.reshape(-1).tolist()), tuple(self.focal_length_m.reshape(-1).tolist()),
               self.relative_illumination, self.camera_equation, None if t is None else tuple(t.reshape(-1).tolist()),
               None if tw is None else tuple(tw.reshape(-1).tolist()), self.margin, self.psf_tolerance,
               self.blur_skip_tolerance, self.max_margin_factor, self._otf_key())
        hit = self._geometry_cache.get(key)
        if hit is None:
            hit = self._geometry_cache[key] = (self._compute_spatial_factors(scene), {})
        return hit

    def _negligible(self, derived: dict, dx, wave, n) -> bool:
        hit = derived.get("negligible")
        if hit is None:
            hit = derived["negligible"] = self.blur_negligible(dx, wave, n)
        return hit

    def _margin(self, derived: dict, shape: tuple[int, int], dx, wave, n) -> int:
        hit = derived.get("margin")
        if hit is None:
            hit = derived["margin"] = self.margin_samples(shape, dx, wave, n)
        return hit

    def _compute_spatial_factors(self, scene: Scene):
        h, w = scene.height, scene.width
        dt, dev = scene.dtype, scene.device
        n, f, d_i, dx = self._geometry(scene)
        mag = -d_i / scene.distance_m
        k = geometry.camera_equation_factor(n, mag, paraxial=self.camera_equation == "paraxial")
        t = self.transmittance_on(scene.wavelengths_nm)
        ys = (torch.arange(h, dtype=dt, device=dev) - (h - 1) / 2)[None, :] * dx[:, None]
        xs = (torch.arange(w, dtype=dt, device=dev) - (w - 1) / 2)[None, :] * dx[:, None]
        ri = geometry.relative_illumination(self.relative_illumination, ys, xs, d_i, n, mag)
        return k, t, ri, n, f, d_i, dx

    def _forward_factored(self, scene: Scene, crop) -> OpticalImage:
        """The optics of a factored scene, exactly (by linearity): the spatial factors multiply the J maps, the
        camera-equation factor and transmittance the J spectra; the maps are transformed once (J rFFTs) and kept
        with the per-wavelength OTF (:class:`FourierFactors`), so the sensor does K inverse FFTs, not L."""
        maps, spectra = scene.factors.maps, scene.factors.spectra
        h, w = scene.height, scene.width
        wave = scene.wavelengths_nm
        (k, t, ri, n, f, d_i, dx), derived = self._geometry_entry(scene)
        spectra = spectra * k.reshape(-1, 1, 1)
        if t is not None:
            spectra = spectra * t.to(device=spectra.device).reshape(1, 1, -1)
        dxb = self._blur_spacing(dx, f, d_i)
        negligible = self._negligible(derived, dxb, wave, n)
        terms = scene.factors.terms
        if not negligible and self._by_used_terms(maps, ri, terms):
            # on CPU each item's used maps only, weighted, padded and transformed (the rest of its spectra are 0)
            margin = self._margin(derived, (h, w), dxb, wave, n)
            spec, (my, mx), (pr, pc), window = self._used_term_spectra(maps, ri, terms, margin, crop)
            otf, inter = self._factored_otf(derived, my, mx, maps.dtype, maps.device, wave, n, dxb)
            factors = FourierFactors(spec, spectra, inter, (my, mx), window,
                                     None if otf is None or otf.is_complex() else otf, terms=terms)
            return self._oi(None, factors, wave, dx, n, f, d_i, crop, h, w, pr, pc, scene.name, derived)
        if ri is not None:
            if (negligible or records_grad(maps, ri)
                    or ri.dtype != maps.dtype or ri.shape[0] not in (1, maps.shape[0])):
                maps = maps * ri
            else:  # consumed by the rFFT below: a reused buffer (no fresh multi-MB allocation per call)
                maps = torch.mul(maps, ri, out=_scratch(tuple(maps.shape), maps.dtype, maps.device, "maps"))
        if negligible:
            # no blur: the irradiance stays maps x spectra (the maps extended like the dense image)
            out, pr, pc = self._extend_unblurred(maps, crop)
            factors = SpectralFactors(out, spectra, validate=False, terms=scene.factors.terms)
        else:
            margin = self._margin(derived, (h, w), dxb, wave, n)
            buf, (pr, pc), window = fft_buffer(maps, (margin, margin), self.pad_mode, window=crop)
            my, mx = buf.shape[-2:]
            otf, inter = self._factored_otf(derived, my, mx, buf.dtype, buf.device, wave, n, dxb)
            if (terms is None or len(terms) == 1 or not per_item_products(buf.device)
                    or records_grad(buf)):
                spec, terms = torch.fft.rfft2(buf), None  # (on an accelerator the padded batch in one launch)
            else:  # on CPU only the maps each item uses (its later ones are 0: so is their transform)
                spec = torch.empty(*buf.shape[:-1], mx // 2 + 1, dtype=buf.dtype.to_complex(), device=buf.device)
                for i, t in enumerate(terms):
                    if t:
                        torch.fft.rfft2(buf[i, :t], out=spec[i, :t])
                    spec[i, t:].zero_()
            factors = FourierFactors(spec, spectra, inter, (my, mx), window,
                                     None if otf is None or otf.is_complex() else otf, terms=terms)
        return self._oi(None, factors, wave, dx, n, f, d_i, crop, h, w, pr, pc, scene.name, derived)

    def _factored_otf(self, derived: dict, my: int, mx: int, dtype, device, wave, n, dx) -> tuple:
        """``(otf or None, OTF for the Fourier-domain product)`` of an ``my x mx`` buffer, memoised in ``derived``."""
        otf_key = ("otf", my, mx, dtype, str(device))
        hit = derived.get(otf_key)
        if hit is None:
            fy, fx = fft_frequencies(my, mx, dx, dtype=dtype, device=device)
            # on CPU, per-item cached rows used as they are (no [B, L, My, Mx', 2] batch copy per call); on an
            # accelerator one stacked OTF (one batched product beats B small kernel launches)
            rows = self._item_otf_rows(fy, fx, wave, n, dx) if per_item_products(device) else None
            if rows is not None and len(rows) > 1 and not rows[0].is_complex():
                hit = (None, tuple(rows))
            else:
                otf = self._otf_fn(wave, n, dx)(fy, fx)
                hit = (otf, self._interleaved(otf))
            if hit[0] is None or not hit[0].requires_grad:
                derived[otf_key] = hit
        return hit

    def _by_used_terms(self, maps: torch.Tensor, ri: torch.Tensor | None, terms) -> bool:
        """Whether the blurred factored path weights, pads and transforms each item's used maps only: per-item terms
        on a CPU (:func:`per_item_products`), no gradient, a pad mode that copies samples (``'zero'``, ``'edge'``:
        the same values as the whole batch's buffer; ``'mean'`` reduces) and an ``ri`` of the maps' dtype and of
        batch 1 or B (multiplied into a reused buffer)."""
        return (terms is not None and len(terms) > 1 and any(terms) and per_item_products(maps.device)
                and self.pad_mode in ("zero", "edge") and not records_grad(maps, ri)
                and (ri is None or (ri.dtype == maps.dtype and ri.shape[0] in (1, maps.shape[0]))))

    def _used_term_spectra(self, maps: torch.Tensor, ri: torch.Tensor | None, terms, margin: int, crop):
        """``(spec [B, J, My, Mx // 2 + 1], (My, Mx), (pad_rows, pad_cols), window)``: the rFFT of the FFT buffer
        (:func:`fft_buffer`) of ``maps x ri``, item ``i``'s terms ``j < terms[i]`` only (the others 0, as their maps).
        Bitwise the whole batch's: the product is elementwise, the pad a copy, each item's rFFT the same batch."""
        b, j, h, w = maps.shape
        spec = None
        for i, t in enumerate(terms):
            if t:
                x = maps[i, :t]
                if ri is not None:
                    x = torch.mul(x, ri[i if ri.shape[0] > 1 else 0],
                                  out=_scratch((t, h, w), maps.dtype, maps.device, "maps"))
                buf, pads, window = fft_buffer(x, (margin, margin), self.pad_mode, window=crop)
                if spec is None:
                    my, mx = buf.shape[-2:]
                    spec = torch.empty(b, j, my, mx // 2 + 1, dtype=buf.dtype.to_complex(), device=buf.device)
                    spec[:i].zero_()
                torch.fft.rfft2(buf, out=spec[i, :t])
            if spec is not None:
                spec[i, t:].zero_()
        return spec, (my, mx), pads, window

    def _extend_unblurred(self, x: torch.Tensor, crop, pad_mode=None) -> tuple[torch.Tensor, int, int]:
        """``x`` (irradiance or maps) extended by the optics' margin like a blurred image would be, or the ``crop``
        window of that extension, when the blur is negligible; returns ``(out, pad_rows, pad_cols)``. ``pad_mode``:
        the optics' own by default."""
        pad_mode = self.pad_mode if pad_mode is None else pad_mode
        h, w = x.shape[-2:]
        pr = pc = 0 if self.margin is None else self.margin
        if crop is None:
            return extend(x, (-pr, h + pr), (-pc, w + pc), pad_mode), pr, pc
        top, left, wh, ww = crop
        if not (wh >= 1 and ww >= 1 and top >= 0 and left >= 0 and top + wh <= h + 2 * pr and left + ww <= w + 2 * pc):
            raise ValueError(f"crop: window {crop} does not fit in the {h + 2 * pr}x{w + 2 * pc} optical image")
        return extend(x, (top - pr, top - pr + wh), (left - pc, left - pc + ww), pad_mode), pr, pc

    def _interleaved(self, otf: torch.Tensor) -> torch.Tensor:
        """A real OTF ``[B, L, My, Mx']`` as ``[B, L, My, Mx', 2]`` (the same value for the real and imaginary
        parts; contiguous, so the Fourier-domain product is a plain elementwise multiply), cached with the OTF."""
        if otf.is_complex() or otf.requires_grad:
            return otf
        hit = self._interleaved_cache.get(id(otf))
        if hit is None or hit[0] is not otf:
            hit = self._interleaved_cache[id(otf)] = (otf, otf[..., None].expand(*otf.shape, 2).contiguous())
        return hit[1]

    def _oi(self, photons, factors, wave, dx, n, f, d_i, crop, h, w, pr, pc, name, derived=None) -> OpticalImage:
        meta = {"full_shape": (h + 2 * pr, w + 2 * pc), "full_pad": (pr, pc)}
        if crop is not None:
            meta["window"] = (crop[0], crop[1])
        # the FOV the OpticalImage would derive from its width and image distance, memoised per geometry and width
        width = (photons if photons is not None else factors).shape[-1]
        hfov = None if derived is None else derived.get(("hfov", width))
        if hfov is None and derived is not None and not (dx.requires_grad or d_i.requires_grad):
            hfov = derived[("hfov", width)] = angle_for_extent(dx * width, d_i)
        return OpticalImage(photons, wave, name=name, metadata=meta, factors=factors, sample_spacing_m=dx,
                            hfov_deg=hfov, focal_length_m=f, f_number=n, image_distance_m=d_i,
                            pad_rows=pr if crop is None else 0, pad_cols=pc if crop is None else 0, validate=False)

    def _blur_to_oi(self, irr, wave, dx, n, f, d_i, crop, name="", fill=None):
        """The optical image of the irradiance ``irr``: blurred (or extended, where the blur is negligible) with the
        optics' pad mode, or, given ``fill`` (the irradiance of a radiance beyond the scene's edges, ``[B, L, 1, 1]``
        or with the relative illumination ``[B, L, H, W]``), by linearity ``irr - fill`` padded with zeros plus
        ``fill`` extended from the edges."""
        h, w = irr.shape[-2:]
        if fill is None:
            out, pr, pc, _ = self._blurred(irr, wave, dx, n, f, d_i, crop, self.pad_mode)
        else:
            out, pr, pc, margin = self._blurred(irr - fill, wave, dx, n, f, d_i, crop, "zero")
            # a constant is kept by any blur (the OTF is 1 at zero frequency); the fill's blur reuses the margin
            # (and so gives the wrap-around warning, if any, once)
            out = out + (fill if fill.shape[-2:] == (1, 1) else
                         self._blurred(fill, wave, dx, n, f, d_i, crop, "edge", margin)[0])
        return self._oi(out, None, wave, dx, n, f, d_i, crop, h, w, pr, pc, name)

    def _blurred(self, irr, wave, dx, n, f, d_i, crop, pad_mode, margin=None) -> tuple[torch.Tensor, int, int, int]:
        """``(out, pad_rows, pad_cols, margin)``: ``irr`` blurred (or extended) with ``pad_mode``; ``margin``
        (samples) as :meth:`margin_samples` gives it unless given."""
        h, w = irr.shape[-2:]
        dxb = self._blur_spacing(dx, f, d_i)
        if self.blur_negligible(dxb, wave, n):
            return (*self._extend_unblurred(irr, crop, pad_mode), 0)
        if margin is None:
            margin = self.margin_samples((h, w), dxb, wave, n)
        out, (pr, pc) = blur_fft(irr, self._otf_fn(wave, n, dxb), dxb, (margin, margin), pad_mode, window=crop)
        return out, pr, pc, margin


def check_transmittance(t: torch.Tensor, name: str = "transmittance") -> None:
    """A lens transmittance: values in [0, 1] (a passive lens transmits at most the light it receives)."""
    check_nonnegative(t, name)
    if bool((t > 1).any()):
        raise ValueError(f"{name}: expected values in [0, 1] (the fraction of the light the lens passes), got a "
                         f"maximum of {t.max().item():.6g}")
