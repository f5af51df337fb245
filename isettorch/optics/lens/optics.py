"""`LensOptics`: scene radiance -> sensor irradiance through a ray-traced lens, shift-variantly.

Per scene wavelength: (1) distortion and lateral colour: the irradiance at image radius r comes from the scene at
the field angle theta with y_lambda(theta) = r (chief ray on the paraxial image plane of the lens's primary
wavelength, ``LensAnalysis.reference_wavelength_nm``); (2) the camera equation on axis (ISETCam
oiCalculateIrradiance: pi / (1 + 4 N^2), object at infinity) times the ray-traced relative illumination
RI_lambda(theta), the scene's flux through the unvignetted pupil over the image area the chief rays map it to
(``LensAnalysis.relative_illumination(method="flux")``; until 2026-11-30 Rimmer's projected solid angle, which made
a field-curved singlet's corners brighter than its centre); (3) a shift-variant PSF: the PSFs on a polar grid of
field heights x azimuths (exact rotations), decomposed into K eigen-PSFs with bilinearly interpolated weights
(``psf.py``). Longitudinal colour is included (every wavelength is imaged on the primary wavelength's paraxial
focus).

Object distance and focus: ``focus_distance_m`` (default infinity) puts the image plane at the primary wavelength's
paraxial image of an object at that distance (a back-focus shift; distances from the object plane to the first lens
vertex). ``object_distance="scene"`` takes each scene's ``distance_m`` as the object distance (one per batch), so a
scene off the focus distance is defocused, by a wavelength-dependent amount (longitudinal colour); the default
``"infinity"`` images every scene as if at infinity (ISETCam's default scene distance, 1.2 m, is only ~24 focal
lengths from a 50 mm lens: a lens focused at infinity would blur it by ~0.2 mm). Tables and PSF banks are cached
per (object distance, focus), distances rounded to 1 um. The image pitch follows the focus: the paraxial
chief-ray height per tan(field angle) on the sensor plane, h (the EFL at infinity focus); the camera equation
takes ISETCam's form (oiCalculateIrradiance: ``pi / (1 + 4 N_w^2)``) at the sensor plane's working f-number
``N_w = N h / f`` (in focus ``N (1 + |m| / m_p)``, m_p the pupil magnification), so the flux on the sensor is the
pupil's whatever the focus and object distance.

Accuracy knob: ``field_samples`` (radial PSF samples), ``azimuth_samples`` and ``components`` (K); the speed and
error of each setting are in ``benchmarks/LENS.md``.

Gradients: the image is differentiable in the scene, not in the prescription. The PSF bank, the relative
illumination and the distortion tables are traced without gradients and cached, and the module has no parameters.
To design a lens through its gradients, use :class:`~isettorch.optics.lens.analysis.LensAnalysis`, whose ray trace
is differentiable in the surfaces (the derivatives of the focal length, distortion and image height in a curvature
agree with central differences: tests/optics/lens).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..._autograd import full_precision
from ...scene.scene import Scene
from .. import geometry
from ..optical_image import OpticalImage
from .analysis import LensAnalysis, _check_pupil_samples
from .psf import ALIASED_STEP_WAVES, chief_ray_heights_mm, geometric_psf, otf_sampler, psf_on_grid, spot_radius_mm
from .trace import TraceError

__all__ = ["LensOptics", "render_brute_force", "field_radii_mm"]


class LensOptics(nn.Module):
    """Shift-variant, wavelength-dependent optics from a lens prescription.

    The PSF kernels (:func:`~isettorch.optics.lens.psf.psf_on_grid`) are the Fourier transform of the pupil's
    one-period PSF cut to the disc of the kernel's window (spot radius + 3 lambda N; the 1-2 % of the light beyond it
    is left out and the kernel renormalised), rotated to each azimuth in the frequency domain
    (:class:`~isettorch.optics.lens.psf.TableOTF`). Against a direct transform of a 256-sample pupil (Cooke triplet,
    1 um pitch, 2026-11-30): kernel L1 error 1.6-2.2 % at 64 pupil samples, 0.6-0.8 % at 128 (4.5-5.1 % and
    3.3-3.9 % when the OTF table was interpolated bilinearly, which replicated the PSF); strongly defocused (an object
    at 0.5 m: the PSF fills the table's period) 1-3.5 % (benchmarks/LENS.md). PSFs are
    interpolated linearly between field heights, spaced more densely towards the field's edge
    (:func:`field_radii_mm`; at 4 um pitch the Cooke triplet's worst interval still errs by 17 % L1, 5 % for the
    double Gauss): raise ``pupil_samples`` and ``field_samples`` for PSF-critical work.

    Two kinds of kernel are made otherwise (``psf.py``): a PSF narrower than 1.5 samples (80 % of its light) is
    shared bilinearly among the samples rather than band-limited (the band-limited samples of a sub-sample PSF ring,
    and their clamped lobes added up to 8 % of light to a uniform scene's centre at a coarse pitch); and where the
    wavefront changes by more than half a wave between the largest pupil grid's samples (the FFT PSF would wrap
    into its period: a singlet's field edge, a strong defocus), the kernel is the geometric spot of the traced rays
    (``geometric_psfs`` lists those (field, wavelength) of the last render's bank).

    Args:
        lens: a :class:`Prescription`, ``.zmx``/``.yaml`` path or bundled lens name.
        field_samples: radial field heights at which PSFs are computed (accuracy knob).
        azimuth_samples: azimuths per field height (PSFs rotated exactly; weights interpolated between).
        components: number of eigen-PSFs K (accuracy knob; ``None`` = all, i.e. only the interpolation error).
        pupil_samples, max_pupil_samples: pupil grid of the FFT PSF, adapted upwards to the wavefront (at most
            ``max_pupil_samples``; only the OTF below the optical image's Nyquist frequency is used).
        max_kernel: largest PSF support (samples); a larger blur raises an error naming it.
        distortion_samples: field angles at which distortion and RI are traced (interpolated between).
        ri_samples: pupil grid (per side) of the relative-illumination integral.
        cache_elements: the per-geometry maps (warp grid, RI x camera equation, eigen-PSF weights, kernel
            spectra) are cached when they hold at most this many values (else recomputed every call).
        transmittance: scalar lens transmittance (absorption and Fresnel losses are not ray traced).
        focus_distance_m: object distance the lens is focused at (m, to the first lens vertex; ``math.inf``, the
            default, also for a lens file designed for a finite object: pass its
            ``prescription.object_distance_mm / 1000`` to focus where its designer did).
        image_plane: ``'paraxial'`` (the default: the primary wavelength's paraxial focus) or ``'prescription'``
            (the file's image surface, where its designer focused it; :class:`LensAnalysis`); None keeps a given
            analysis's.
        object_distance: ``"infinity"`` (default: every scene imaged as if at infinity), ``"scene"`` (each
            scene's ``distance_m``) or a distance in m.

    Buffers ``focal_length_m`` and ``f_number`` report the traced lens's (its prescription's stop and powers set
    them): they are read, not settable; the camera equation and the PSFs use the lens's own (an edit of the buffer
    changed the camera equation until the first render cached it, and never the PSFs).
    """

    def __init__(self, lens, *, field_samples: int = 13, azimuth_samples: int = 24, components: int | None = 16,
                 pupil_samples: int = 64, max_pupil_samples: int = 256, max_kernel: int = 129,
                 distortion_samples: int = 16, ri_samples: int = 64, cache_elements: int = 64 * 2**20,
                 transmittance: float = 1.0, focus_distance_m: float = math.inf,
                 object_distance: str | float = "infinity", image_plane: str | None = None,
                 dtype=torch.float64):
        super().__init__()
        if not (isinstance(focus_distance_m, (int, float)) and float(focus_distance_m) > 0):
            raise ValueError(f"focus_distance_m: expected a positive distance in m (math.inf for infinity), got "
                             f"{focus_distance_m!r}")
        if not (object_distance in ("infinity", "scene") or (isinstance(object_distance, (int, float))
                                                              and float(object_distance) > 0)):
            raise ValueError(f"object_distance: expected 'infinity', 'scene' or a positive distance in m, got "
                             f"{object_distance!r}")
        self.focus_distance_m = float(focus_distance_m)
        self.object_distance = object_distance
        a = lens if isinstance(lens, LensAnalysis) else LensAnalysis(lens, image_plane=image_plane or "paraxial")
        if image_plane is not None and a.image_plane != image_plane:
            a = LensAnalysis(a, dtype=a.dtype, object_distance_mm=a.object_distance_mm,
                             focus_distance_mm=a.focus_distance_mm, image_plane=image_plane)
        if a.focus_distance_mm != self.focus_distance_m * 1e3 or not math.isinf(a.object_distance_mm):
            a = a.at(math.inf, self.focus_distance_m * 1e3)
        self.analysis = a  # object at infinity, this focus
        for name, v, lo in (("field_samples", field_samples, 2), ("azimuth_samples", azimuth_samples, 1),
                            ("pupil_samples", pupil_samples, 16), ("distortion_samples", distortion_samples, 4)):
            if not isinstance(v, int) or v < lo:
                raise ValueError(f"{name}: expected an int >= {lo}, got {v!r}")
        if components is not None and (not isinstance(components, int) or components < 1):
            raise ValueError(f"components: expected None or an int >= 1, got {components!r}")
        if not 0 < transmittance <= 1:
            raise ValueError(f"transmittance: expected a value in (0, 1], got {transmittance}")
        self.field_samples, self.azimuth_samples, self.components = field_samples, azimuth_samples, components
        self.max_pupil_samples = int(max_pupil_samples)
        self.pupil_samples, self.max_kernel, self.distortion_samples = pupil_samples, max_kernel, distortion_samples
        self.transmittance = float(transmittance)
        self.ri_samples = _check_pupil_samples(ri_samples, "ri_samples")
        self.cache_elements = int(cache_elements)
        a = self.analysis
        self.register_buffer("focal_length_m", (a.effective_focal_length_mm.detach() * 1e-3).to(dtype))
        self.register_buffer("f_number", a.f_number.detach().to(dtype))
        self._cache: dict = {}
        #: the (field, wavelength) whose kernels are the geometric spot of the rays (psf.geometric_psf), in the
        #: PSF bank of the last render
        self.geometric_psfs: list = []
        self._states = {_conjugate_key(math.inf, self.focus_distance_m): (a, self._cache)}
        self._a, self._c = a, self._cache

    def _use(self, object_distance_m: float):
        """Select (creating if new) the analysis and cache of one (object distance, focus) conjugate."""
        key = _conjugate_key(object_distance_m, self.focus_distance_m)
        if key not in self._states:
            self._states[key] = (self.analysis.at(object_distance_m * 1e3, self.focus_distance_m * 1e3), {})
        self._a, self._c = self._states[key]
        return self._a

    # --- per-wavelength lens data (cached) ------------------------------------------------------------
    def _radial_tables(self, wavelength_nm: float):
        key = ("radial", round(wavelength_nm, 6))
        if key not in self._c:
            a = self._a
            fr = torch.linspace(0, 1, self.distortion_samples, dtype=torch.float64)
            with torch.no_grad():
                y = chief_ray_heights_mm(a, fr, wavelength_nm)
                ri = a._flux_illumination(fr.tolist(), wavelength_nm, self.ri_samples)
            if not bool(torch.isfinite(ri).all()):
                raise TraceError(f"{a.prescription.name}: the chief ray's height stops growing with field at "
                                 f"{wavelength_nm} nm (fields {fr[~torch.isfinite(ri)].tolist()}); the image folds "
                                 f"back there and has no relative illumination")
            if not bool((y[1:] > y[:-1]).all()):
                raise TraceError(f"{a.prescription.name}: chief-ray height is not increasing with field at "
                                 f"{wavelength_nm} nm; the distortion cannot be inverted")
            self._c[key] = (fr * a.max_field_deg, y, ri)
        return self._c[key]

    @property
    def image_distance_m(self) -> float:
        """Image height on the sensor per tan(field angle) of an object at infinity (m): the focal length when the lens
        is focused at infinity, more when focused nearer (its image plane moves back), as the optical image's
        ``image_distance_m`` reports it; the image distance a scene's field of view is sized with for one scene
        sample per pixel."""
        return float(self.analysis.image_height_per_tan_mm()) * 1e-3

    def chief_ray_angle_table(self, wavelength_nm: float | None = None) -> dict:
        """The traced image-space chief-ray angle against image height on the sensor plane, at ``wavelength_nm``
        (default: the lens's primary wavelength) and ``distortion_samples`` fields (cached):
        ``{'image_height_m': [N], 'cra_deg': [N]}``; the angle is positive when the chief ray travels away from the
        axis (the sensor's pixel optics read it, ``Sensor(pixel_optics)``)."""
        if wavelength_nm is None:
            wavelength_nm = self._a.reference_wavelength_nm
        key = ("cra", round(wavelength_nm, 6))
        if key not in self._c:
            a = self._a
            fr = torch.linspace(0, 1, self.distortion_samples, dtype=torch.float64)
            with torch.no_grad():
                y_mm = chief_ray_heights_mm(a, fr, wavelength_nm)
                cra = torch.stack([a.chief_ray_angle_deg(float(f), wavelength_nm) for f in fr.tolist()])
            sign = torch.where(y_mm < 0, -1.0, 1.0).to(cra)
            self._c[key] = {"image_height_m": (y_mm.abs() * 1e-3).to(torch.float64),
                            "cra_deg": (cra * sign).to(torch.float64)}
        return self._c[key]

    def _psf_stack(self, wavelengths_nm: tuple[float, ...], dx_mm: float, r_max_mm: float):
        """PSFs ``[L, F, A, s, s]`` on the polar (field height x azimuth) grid, cached."""
        key = ("psfs", wavelengths_nm, round(dx_mm, 12), round(r_max_mm, 9), self.field_samples,
               self.azimuth_samples, self.pupil_samples)
        if key in self._c:
            return self._c[key]
        a = self._a
        theta_ref, y_ref, _ = self._radial_tables(a.reference_wavelength_nm)
        radii = field_radii_mm(r_max_mm, self.field_samples)
        fields = (_interp(radii, y_ref, theta_ref) / a.max_field_deg).clamp(0, 1)
        reach = 0.0
        for f in (fields[0], fields[-1], fields[len(fields) // 2]):
            for wl in (wavelengths_nm[0], wavelengths_nm[-1]):
                reach = max(reach, spot_radius_mm(a, float(f), wl))
        reach += 3.0 * max(wavelengths_nm) * 1e-6 * float(self.analysis.f_number)
        size = max(2 * int(math.ceil(reach / dx_mm)) + 1, 3)
        if size > self.max_kernel:
            raise ValueError(f"max_kernel: the lens's PSF spans {size} samples at {dx_mm * 1e3:.3g} um pitch, more "
                             f"than max_kernel={self.max_kernel}; raise it or use a coarser optical-image grid")
        az = torch.arange(self.azimuth_samples, dtype=torch.float64) * (2 * math.pi / self.azimuth_samples)
        psfs = torch.empty(len(wavelengths_nm), self.field_samples, self.azimuth_samples, size, size,
                           dtype=torch.float64)
        geometric: list = []
        with torch.no_grad():
            for i, wl in enumerate(wavelengths_nm):
                for k, f in enumerate(fields.tolist()):
                    otf = otf_sampler(a, f, wl, self.pupil_samples, self.max_pupil_samples)
                    if otf.max_step_waves > ALIASED_STEP_WAVES:  # the FFT PSF wraps into its period
                        psfs[i, k] = geometric_psf(a, f, wl, az, dx_mm, size)
                        geometric.append((round(f, 4), wl))
                    else:
                        psfs[i, k] = psf_on_grid(otf, az, dx_mm, size)
        self._c[key] = (psfs, radii, size, tuple(geometric))
        return self._c[key]

    def _psf_bank(self, wavelengths_nm: tuple[float, ...], dx_mm: float, r_max_mm: float):
        key = ("bank", wavelengths_nm, round(dx_mm, 12), round(r_max_mm, 9), self.field_samples,
               self.azimuth_samples, self.pupil_samples, self.components)
        if key in self._c:
            return self._c[key]
        psfs, radii, size, geometric = self._psf_stack(wavelengths_nm, dx_mm, r_max_mm)
        flat = psfs.reshape(-1, size * size)
        if self.components is None or self.components >= min(flat.shape):
            basis, coeff = None, psfs
        else:
            # eigen-PSFs: the leading right singular vectors of the PSF set (all fields, azimuths, wavelengths)
            _, _, vh = torch.linalg.svd(flat, full_matrices=False)
            basis = vh[: self.components]  # [K, size^2]
            coeff = (flat @ basis.T).reshape(*psfs.shape[:3], -1)  # [L, F, A, K]
        bank = {"psfs": psfs, "basis": basis, "coeff": coeff, "radii": radii, "size": size, "geometric": geometric}
        self._c[key] = bank
        return bank

    def clear_cache(self) -> None:
        for _, c in self._states.values():
            c.clear()

    # --- per-geometry plan (cached) ----------------------------------------------------------------
    def _plan(self, waves, h, w, t_pitch, corner_deg, dt, dev):
        key = ("plan", waves, h, w, round(t_pitch, 15), str(dt), str(dev), self.field_samples, self.azimuth_samples,
               self.components)
        if key in self._c:
            return self._c[key]
        a = self._a
        efl_mm = float(a.image_height_per_tan_mm())
        dx_mm = efl_mm * t_pitch
        # image radius reached by the corners, any wavelength
        r_max = max(float(_interp(torch.tensor([corner_deg], dtype=torch.float64), *self._radial_tables(wl)[:2])[0])
                    for wl in (waves[0], waves[-1], a.reference_wavelength_nm))
        bank = self._psf_bank(waves, dx_mm, r_max * 1.0001)
        m = bank["size"] // 2
        hh, ww = h + 2 * m, w + 2 * m
        yy = (torch.arange(hh, dtype=torch.float64) - (hh - 1) / 2) * dx_mm
        xx = (torch.arange(ww, dtype=torch.float64) - (ww - 1) / 2) * dx_mm
        gy, gx = torch.meshgrid(yy, xx, indexing="ij")
        r = torch.sqrt(gx * gx + gy * gy)
        phi = torch.atan2(gx, gy) % (2 * math.pi)  # from +y towards +x
        w_r, i_r = _lin_index(r, bank["radii"])
        pa = phi / (2 * math.pi / self.azimuth_samples)
        i_a0 = torch.floor(pa).long() % self.azimuth_samples
        w_a = pa - torch.floor(pa)
        i_a1 = (i_a0 + 1) % self.azimuth_samples
        fft_shape = (_fast(hh + 2 * m), _fast(ww + 2 * m))
        plan = {"m": m, "hh": hh, "ww": ww, "fft_shape": fft_shape, "bank": bank, "gx": gx, "gy": gy, "r": r,
                "polar": (i_r, w_r, i_a0, i_a1, w_a), "t_pitch": t_pitch, "h": h, "w": w, "waves": waves,
                "dt": dt, "dev": dev, "efl_mm": efl_mm, "bands": None}
        if bank["basis"] is not None:
            k = bank["basis"].shape[0]
            kern = bank["basis"].reshape(k, 2 * m + 1, 2 * m + 1).to(dt).to(dev)
            plan["kspec"] = torch.fft.rfft2(kern, s=fft_shape)
        per_band = hh * ww * (3 + (bank["basis"].shape[0] if bank["basis"] is not None else 0))
        if per_band * len(waves) <= self.cache_elements:
            plan["bands"] = [self._band(plan, li) for li in range(len(waves))]
        self._c[key] = plan
        return plan

    def _band(self, plan, li):
        """Warp grid ``[1, hh, ww, 2]``, gain (camera equation x RI) and eigen-PSF weights of band ``li``."""
        wl = plan["waves"][li]
        dt, dev, r, w, h = plan["dt"], plan["dev"], plan["r"], plan["w"], plan["h"]
        theta_t, y_t, ri_t = self._radial_tables(wl)
        r_c = r.clamp(max=float(y_t[-1]))
        # tan(theta) is nearly linear in r and RI nearly linear in r^2: interpolate those (smooth, even laws)
        t = _interp(r_c, y_t, torch.tan(torch.deg2rad(theta_t)))
        ri = _interp(r_c * r_c, y_t * y_t, ri_t) * (r <= y_t[-1])
        scale = torch.where(r > 0, t / torch.where(r > 0, r, torch.ones_like(r)),
                            torch.full_like(r, 1.0 / plan["efl_mm"]))
        src_x = plan["gx"] * scale / plan["t_pitch"]  # scene samples from the centre
        src_y = plan["gy"] * scale / plan["t_pitch"]
        grid = torch.stack([src_x / (w / 2), src_y / (h / 2)], -1)[None].to(dt).to(dev)
        # camera equation on axis (ISETCam oiCalculateIrradiance's form) x transmittance x RI, at the sensor plane's
        # working f-number N h / f: h, the chief-ray height per tan(field angle) on the sensor (the pitch's), is
        # f (1 + |m| / m_p) in focus (m_p the pupil magnification; Smith, Modern Optical Engineering, ch. 9) and grows
        # with a back-focus shift, so the flux on the sensor, E x pitch^2, is that of the pupil whatever the focus.
        # The object plane's 1 + |m| (ISETCam's) did not follow the sensor: an object at infinity with the Cooke
        # triplet focused at 0.5 m put 1.22x the flux on the sensor, an object at 0.5 m focused at infinity 0.82x.
        h_over_f = plan["efl_mm"] / float(self._a.effective_focal_length_mm)
        n_w = self.analysis.f_number.detach().double() * h_over_f
        k0 = float(geometry.camera_equation_factor(n_w, 0.0)) * self.transmittance
        band = {"grid": grid, "gain": (k0 * ri).to(dt).to(dev)}
        if plan["bank"]["basis"] is not None:
            band["weights"] = _bilinear_polar(plan["bank"]["coeff"][li], *plan["polar"]).to(dt).to(dev)
        return band

    # --- forward ----------------------------------------------------------------------------------------
    @full_precision
    def forward(self, scene: Scene, crop: tuple[int, int, int, int] | None = None) -> OpticalImage:
        """Scene -> `OpticalImage` ``(B, L, H + 2 m, W + 2 m)``, m = PSF half-width, photons/s/m^2/nm."""
        if not isinstance(scene, Scene):
            raise TypeError(f"scene: expected a Scene, got {type(scene).__name__}")
        # a factored scene (core's maps x spectra) would be densified here: x = scene.to_dense().photons
        x = scene.photons
        b, nl, h, w = x.shape
        dt, dev = x.dtype, x.device
        hfov = scene.hfov_deg.reshape(-1)
        if not bool((hfov == hfov[0]).all()):
            raise ValueError(f"scene.hfov_deg: LensOptics needs one field of view per batch, got {hfov.tolist()}")
        if self.object_distance == "scene":
            dist = scene.distance_m.reshape(-1) if isinstance(scene.distance_m, torch.Tensor) else \
                torch.tensor([float(scene.distance_m)])
            if not bool((dist == dist[0]).all()):
                raise ValueError(f"scene.distance_m: LensOptics(object_distance='scene') needs one distance per "
                                 f"batch, got {dist.tolist()}")
            d_obj = float(dist[0])
        else:
            d_obj = math.inf if self.object_distance == "infinity" else float(self.object_distance)
        a = self._use(d_obj)
        half_t = math.tan(math.radians(float(hfov[0]) / 2))
        t_pitch = 2 * half_t / w  # tan(angle) per scene sample
        corner_t = t_pitch * math.hypot(w / 2, h / 2)
        corner_deg = math.degrees(math.atan(corner_t))
        if corner_deg > a.max_field_deg * (1 + 1e-9) and a.max_field_deg == 0:
            raise TraceError(f"{a.prescription.name}: the prescription has no off-axis field (its largest field "
                             f"angle is 0 deg) and LensOptics traces the field up to it; add field angles (YFLN or "
                             f"field_angles_deg) reaching the scene's corners, {corner_deg:.3f} deg")
        if corner_deg > a.max_field_deg * (1 + 1e-9):
            max_hfov = 2 * math.degrees(math.atan(math.tan(math.radians(a.max_field_deg)) * w / math.hypot(w, h)))
            raise TraceError(f"scene.hfov_deg: the scene's corners are {corner_deg:.3f} deg off axis, beyond the "
                             f"lens's largest field {a.max_field_deg} deg; reduce hfov_deg to at most "
                             f"{max_hfov:.3f}")
        efl_mm = float(a.image_height_per_tan_mm())  # the EFL at infinity focus
        dx_mm = efl_mm * t_pitch  # ideal (distortion-free) image pitch
        waves = tuple(float(v) for v in scene.wavelengths_nm.tolist())
        plan = self._plan(waves, h, w, t_pitch, corner_deg, dt, dev)
        self.geometric_psfs = list(plan["bank"]["geometric"])
        m, hh, ww, fft_shape = plan["m"], plan["hh"], plan["ww"], plan["fft_shape"]
        out = torch.zeros(b, nl, hh, ww, dtype=dt, device=dev)
        # the full-PSF path's polar interpolation (the plan's, on the CPU) on the image's device, once per call
        pol = None if plan["bank"]["basis"] is not None else tuple(t.to(dev) for t in plan["polar"])
        for li in range(nl):
            band = plan["bands"][li] if plan["bands"] is not None else self._band(plan, li)
            img = F.grid_sample(x[:, li:li + 1], band["grid"].expand(b, -1, -1, -1), mode="bilinear",
                                padding_mode="zeros", align_corners=False)[:, 0]  # [B, hh, ww]
            irr = img * band["gain"]
            if pol is not None:
                out[:, li] = _apply_full(irr, plan["bank"]["psfs"][li], *pol, m)
                continue
            src = irr[:, None] * band["weights"][None]  # [B, K, hh, ww]
            acc = (torch.fft.rfft2(src, s=fft_shape) * plan["kspec"][None]).sum(1)
            full = torch.fft.irfft2(acc, s=fft_shape)
            out[:, li] = full[:, m:m + hh, m:m + ww]
        fl = self.focal_length_m.to(dt).expand(b)
        # image distance as the sensor's FOV sizing reads it: image height per tan(field angle) (EFL at infinity)
        d_img = fl if math.isinf(self.focus_distance_m) else torch.full((b,), efl_mm * 1e-3, dtype=dt, device=dev)
        meta = {"full_shape": (hh, ww), "full_pad": (m, m), "psf_size": 2 * m + 1,
                "object_distance_m": d_obj, "focus_distance_m": self.focus_distance_m,
                "chief_ray_angle": self.chief_ray_angle_table()}
        res = OpticalImage(out, scene.wavelengths_nm, name=scene.name, metadata=meta,
                           sample_spacing_m=torch.full((b,), dx_mm * 1e-3, dtype=dt, device=dev), focal_length_m=fl,
                           f_number=self.f_number.to(dt).expand(b), image_distance_m=d_img, pad_rows=m, pad_cols=m,
                           validate=False)
        if crop is not None:
            top, left, ch, cw = crop
            res = res.crop(top, left, ch, cw)
            res.metadata["window"] = (top, left)
        return res


def _fast(n: int) -> int:
    from ..blur import next_fast_size

    return next_fast_size(n)


def _interp(xq: torch.Tensor, xp: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
    """Piecewise-linear interpolation (numpy.interp semantics, clamped at the ends)."""
    xp, fp = xp.to(xq.dtype), fp.to(xq.dtype)
    idx = torch.searchsorted(xp, xq.contiguous().clamp(xp[0], xp[-1])).clamp(1, len(xp) - 1)
    x0, x1 = xp[idx - 1], xp[idx]
    t = (xq.clamp(xp[0], xp[-1]) - x0) / (x1 - x0)
    return fp[idx - 1] + t * (fp[idx] - fp[idx - 1])


def field_radii_mm(r_max_mm: float, samples: int) -> torch.Tensor:
    """Image radii (mm) of the PSF grid's field heights: ``r_max (5 u - 2 u^2) / 3`` for ``u`` uniform in [0, 1], so
    the step shrinks linearly from 5/3 of the uniform step on axis to 1/3 of it at ``r_max``.

    A lens's PSF changes fastest towards the field's edge (aberrations grow with field height, vignetting sets in),
    and linear interpolation between field heights errs there most. Measured (2026-11-30, 13 field heights, 550 nm,
    the largest L1 error of the interpolated PSF at a quarter, half and three quarters of each interval, against the
    PSF computed there; uniform grid -> this one): Cooke triplet, last interval 46.6 -> 16.1 % at 4 um pitch, 48.9 ->
    17.5 % at 2 um (largest over all intervals 17.0 / 18.3 %; mean over the intervals 9.9 -> 8.9 %, 10.3 -> 9.3 %);
    double Gauss 8.9 -> 2.4 % and 11.2 -> 5.1 % (largest 5.2 / 5.4 %; mean 3.7 -> 3.5 %, 4.1 -> 4.1 %). The first
    interval's error grows from 0.7-1.4 % to 1.8-3.7 %. (A step of 3/2 to 1/2 halved the worst errors only; cubic
    interpolation between field heights, tried on the uniform grid, lowered the mean but not the edge's error.)"""
    u = torch.linspace(0, 1, samples, dtype=torch.float64)
    return r_max_mm * (5.0 * u - 2.0 * u * u) / 3.0


def _lin_index(v: torch.Tensor, grid: torch.Tensor):
    """Lower index and weight of ``v`` in an increasing ``grid`` (clamped to its ends)."""
    g = grid.to(v.dtype)
    vc = v.clamp(float(g[0]), float(g[-1]))
    i = (torch.searchsorted(g, vc.contiguous(), right=True) - 1).clamp(0, len(g) - 2)
    w = (vc - g[i]) / (g[i + 1] - g[i])
    return w, i


def _bilinear_polar(coeff, i_r, w_r, i_a0, i_a1, w_a):
    """Weights ``[K, H, W]`` bilinear in (field height, azimuth) from ``coeff [F, A, K]``."""
    c00, c01 = coeff[i_r, i_a0], coeff[i_r, i_a1]
    c10, c11 = coeff[i_r + 1, i_a0], coeff[i_r + 1, i_a1]
    wr, wa = w_r[..., None], w_a[..., None]
    v = (1 - wr) * ((1 - wa) * c00 + wa * c01) + wr * ((1 - wa) * c10 + wa * c11)
    return v.permute(2, 0, 1)


def _apply_full(irr, psfs, i_r, w_r, i_a0, i_a1, w_a, m, block_rows: int = 64):
    """Every source sample spread with its own interpolated PSF (the reference the eigen-PSFs approximate),
    in blocks of source rows to bound memory."""
    s = 2 * m + 1
    # the band's PSF table lives on the CPU (the plan's): moved to the image's device (the products of CUDA sources
    # and CPU kernels failed); the polar weights come on it
    coeff = psfs.reshape(psfs.shape[0], psfs.shape[1], s * s).to(irr.device)
    b, hh, ww = irr.shape
    out = torch.zeros(b, hh + 2 * m, ww + 2 * m, dtype=irr.dtype, device=irr.device)
    for r0 in range(0, hh, block_rows):
        r1 = min(hh, r0 + block_rows)
        sl = slice(r0, r1)
        kern = _bilinear_polar(coeff, i_r[sl], w_r[sl], i_a0[sl], i_a1[sl], w_a[sl]).to(irr.dtype)
        src = irr[:, sl]
        for dy in range(s):
            for dx in range(s):
                out[:, r0 + dy:r1 + dy, dx:dx + ww] += src * kern[dy * s + dx]
    return out[:, m:m + hh, m:m + ww]


def render_brute_force(optics: LensOptics, scene: Scene, field_samples: int = 33,
                       azimuth_samples: int = 64) -> OpticalImage:
    """Reference render: every source sample spread by its own PSF (polar PSF grid as fine as asked, no
    low-rank step); for the accuracy table and tests only (slow)."""
    ref = LensOptics(optics.analysis, field_samples=field_samples, azimuth_samples=azimuth_samples,
                     components=None, pupil_samples=optics.pupil_samples,
                     max_pupil_samples=optics.max_pupil_samples, max_kernel=optics.max_kernel,
                     distortion_samples=optics.distortion_samples, ri_samples=optics.ri_samples,
                     transmittance=optics.transmittance)
    ref.focus_distance_m, ref.object_distance = optics.focus_distance_m, optics.object_distance
    ref._states = {k: (a, {kk: v for kk, v in c.items() if kk[0] in ("radial", "psfs")})  # shared tables
                   for k, (a, c) in optics._states.items()}
    ref.analysis, ref._cache = optics.analysis, ref._states[_conjugate_key(math.inf, optics.focus_distance_m)][1]
    return ref(scene)


def _conjugate_key(object_distance_m: float, focus_distance_m: float) -> tuple:
    """Cache key of a conjugate: distances rounded to 1 um (infinity kept)."""
    return tuple(v if math.isinf(v) else round(v, 6) for v in (float(object_distance_m), float(focus_distance_m)))
