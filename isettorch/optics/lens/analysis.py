"""Lens analysis from real rays with OpticStudio's default conventions (the file's object distance, infinity for
camera lenses; no ray aiming), except
for the image plane: here the primary wavelength's paraxial focus, where OpticStudio takes the file's image surface
(the last thickness, which a designer sets to the best focus). The two differ for the bundled Cooke triplet by
0.229 mm (its file focuses inside the paraxial focus: on-axis MTF at 20 / 40 cycles/mm 0.51 / 0.20 here against
0.84 / 0.56 on the file's plane; RMS spot 14.3 against 4.8 um) and for the aspheric singlet by 0.234 mm (its
optiland file leaves the r^2 asphere term out of the paraxial focus); the double Gauss's file plane is its paraxial
focus. ``LensOptics`` renders on this plane too.

* Paraxial data (EFL, F-number, back focal length, pupils, the focus) at the lens's primary wavelength, as
  OpticStudio reports them (the file's ``PWAV``, OpticStudio's default the first wavelength; a YAML lens without
  ``primary_wavelength_nm``: its listed wavelength nearest :data:`REFERENCE_WAVELENGTH_NM` = 587.6 nm, the d line).
  Below, "primary" means that wavelength.
* Rays fill the paraxial entrance pupil (diameter and position from the paraxial trace at the primary wavelength)
  for every field and wavelength; the chief ray passes through its centre; clear apertures clip, the stop does not.
  With an ``FNUM`` aperture the EPD is EFL / F# at the primary wavelength (OpticStudio's image-space F/#).
* Image height: chief ray on the paraxial image plane of its own wavelength (not the sensor plane of the MTF and
  of ``LensOptics``: across wavelengths this shows the longitudinal colour as lateral, 29.5 um for the Cooke
  triplet's 486 / 656 nm at full field against 0.6 um on the sensor plane); distortion
  100 (y - F tan(theta)) / (F tan(theta)) with F the EFL at the primary wavelength (OpticStudio "F-Tan(Theta)"
  distortion).
* Relative illumination: projected solid angle (area in direction-cosine space) of the vignetted image-space beam,
  relative to the on-axis beam at the same wavelength (OpticStudio's "Relative Illumination", after
  M. Rimmer, "Relative illumination calculations", Proc. SPIE 655, 1986): integral of |d(L,M)/d(px,py)| over
  the unvignetted pupil; and the scene's flux through the pupil over the area the chief ray maps it to
  (``method="flux"``, what ``LensOptics`` applies: it holds where Rimmer's does not, on field-curved or aberrated
  beams; :meth:`LensAnalysis.relative_illumination`).
* Diffraction PSF/MTF: FFT of the pupil function A exp(2 pi i W / lambda), W = OPD to the reference sphere
  centred on the chief ray's image point through the paraxial exit pupil (Goodman, *Introduction to Fourier
  Optics*, 3rd ed., ch. 6), image plane at the primary wavelength's paraxial focus; frequency scale from the real
  marginal rays' direction cosines: cutoff = n' |M(0, +1) - M(0, -1)| / lambda (tangential), the same with L (sagittal).

Finite conjugates (``object_distance_mm``, ``focus_distance_mm``; both default to the prescription's
``object_distance_mm``, the conjugate the file was designed for: infinity for camera lenses, which is exactly the
lens-report convention above). Distances are measured from the object (or focus) plane to the first lens vertex
(OpticStudio's object-surface thickness). The field stays an angle theta from the entrance-pupil centre: the object
point lies at height -(D + z_EP) tan(theta) on the plane z = -D, so the chief ray is the same ray as at infinity;
rays leave the object point aimed at the paraxial entrance pupil, starting (optical path 0) on the spherical
wavefront about it through the entrance-pupil centre. Paraxial image of an object at D: y-nu trace (Smith, *Modern
Optical Engineering*, 4th ed., ch. 3) of the axial ray y_1 = 1, u_0 = 1 / D; image distance from the last vertex l'
= -y_k / u'_k; magnification m = n u_0 / (n' u'_k) (Lagrange invariant). Focus: the image plane ("sensor") is the
paraxial image of an object at ``focus_distance_mm`` at the primary wavelength (a back-focus shift); an object at
another distance, or another wavelength (longitudinal colour, through the glasses' dispersion), is then out of focus
there, which the pupil function carries as OPD to the reference sphere centred on the chief ray's point on that
plane.
"""

from __future__ import annotations

import math

import torch

from ..._checks import is_integer
from .prescription import DEFAULT_PRIMARY_NM, Prescription, load_lens
from .trace import LensGeometry, RayBundle, TraceError

__all__ = ["LensAnalysis", "lens_report", "REFERENCE_WAVELENGTH_NM"]

#: Primary wavelength (nm) of a lens that states none (``Prescription.primary_wavelength_nm``'s default).
REFERENCE_WAVELENGTH_NM = DEFAULT_PRIMARY_NM


class LensAnalysis:
    """Real-ray analysis of one lens (caches paraxial data per wavelength).

    Args:
        lens: a :class:`Prescription`, a path or a bundled lens name.
        curvature_per_mm: optional ``[S]`` tensor of the lens surfaces' curvatures (for gradients).
        object_distance_mm, focus_distance_mm: the object and the distance focused at (mm to the first vertex;
            ``math.inf`` for infinity; module docstring); None (the default) for the prescription's
            ``object_distance_mm``, the conjugate it was designed for (infinity for most camera lenses).
        image_plane: the sensor plane (:attr:`sensor_z`): ``'paraxial'`` (the primary wavelength's paraxial focus)
            or ``'prescription'`` (the file's image surface, :attr:`prescription_image_distance_mm`).

    Paraxial quantities are computed at :attr:`reference_wavelength_nm`, the prescription's primary wavelength.
    """

    def __init__(self, lens, curvature_per_mm: torch.Tensor | None = None, dtype=torch.float64, *,
                 object_distance_mm: float | None = None, focus_distance_mm: float | None = None,
                 image_plane: str = "paraxial"):
        if isinstance(lens, LensAnalysis):
            self.prescription, self.geometry = lens.prescription, lens.geometry
        else:
            self.prescription: Prescription = load_lens(lens)
            self.geometry = LensGeometry(self.prescription, curvature_per_mm, dtype=dtype)
        if image_plane not in IMAGE_PLANES:
            raise ValueError(f"image_plane: expected one of {IMAGE_PLANES}, got {image_plane!r}")
        if image_plane == "prescription" and self.prescription_image_distance_mm is None:
            raise ValueError(f"image_plane: 'prescription' needs the file's image distance (the last surface's "
                             f"thickness > 0); {self.prescription.name!r} has none")
        self.image_plane = image_plane
        design_mm = self.prescription.object_distance_mm
        object_distance_mm = design_mm if object_distance_mm is None else object_distance_mm
        focus_distance_mm = design_mm if focus_distance_mm is None else focus_distance_mm
        for name, v in (("object_distance_mm", object_distance_mm), ("focus_distance_mm", focus_distance_mm)):
            if not (isinstance(v, (int, float)) and float(v) > 0):
                raise ValueError(f"{name}: expected a positive distance (mm, object plane to the first lens vertex; "
                                 f"math.inf for infinity), got {v!r}")
        self.object_distance_mm = float(object_distance_mm)
        self.focus_distance_mm = float(focus_distance_mm)
        self.dtype = dtype
        self._par: dict = {}

    def at(self, object_distance_mm: float = math.inf, focus_distance_mm: float = math.inf) -> LensAnalysis:
        """The same lens (shared geometry and image-plane convention) at another object distance and focus."""
        return LensAnalysis(self, dtype=self.dtype, object_distance_mm=object_distance_mm,
                            focus_distance_mm=focus_distance_mm, image_plane=self.image_plane)

    @property
    def prescription_image_distance_mm(self) -> float | None:
        """The file's image distance: the last lens surface's thickness to the image surface (mm; None when the file
        gives none, 0 or less)."""
        surfaces = self.prescription.surfaces
        t = surfaces[-2].thickness_mm if len(surfaces) >= 3 else 0.0
        return float(t) if math.isfinite(t) and t > 0 else None

    def paraxial(self, wavelength_nm: float) -> dict:
        key = round(float(wavelength_nm), 6)
        if key not in self._par or self.geometry.curvature.requires_grad:
            self._par[key] = self.geometry.paraxial(wavelength_nm)
        return self._par[key]

    @property
    def reference_wavelength_nm(self) -> float:
        """The wavelength of the paraxial data: the prescription's primary wavelength (nm)."""
        return float(self.prescription.primary_wavelength_nm)

    @property
    def ref(self) -> dict:
        """Paraxial data at the primary wavelength."""
        return self.paraxial(self.reference_wavelength_nm)

    @property
    def effective_focal_length_mm(self) -> torch.Tensor:
        return self.ref["efl"]

    @property
    def f_number(self) -> torch.Tensor:
        """Paraxial image-space f-number ``|EFL| / EPD`` at the primary wavelength (object at infinity); positive
        for a negative lens too, as the FNUM aperture's ``EPD = |EFL| / F#`` and the working f-number read it."""
        return self.ref["efl"].abs() / self.ref["epd"]

    @property
    def max_field_deg(self) -> float:
        return self.prescription.max_field_deg

    def paraxial_image_distance_mm(self, wavelength_nm: float, object_distance_mm: float | None = None):
        """Paraxial image of an axial object at ``object_distance_mm`` (default: this analysis's object
        distance) at ``wavelength_nm``, from the last lens vertex (mm); the back focal length at infinity."""
        d = self.object_distance_mm if object_distance_mm is None else float(object_distance_mm)
        if math.isinf(d):
            return self.paraxial(wavelength_nm)["bfl"]
        return self._finite_axial(wavelength_nm, d)[0]

    def _finite_axial(self, wavelength_nm, d):
        """y-nu trace of the axial ray y_1 = 1, u_0 = 1 / d: (image distance from the last vertex, u_0, u'_k)."""
        g = self.geometry
        n = g.indices(wavelength_nm)
        one = torch.ones((), dtype=self.dtype)
        u0 = one / d
        ys, u = g._paraxial_trace(one, u0, n)
        if float(u.detach()) == 0:
            raise TraceError(f"object_distance_mm: an object at {d} mm is imaged at infinity by "
                             f"{self.prescription.name} (it lies in the front focal plane)")
        return -ys[-1] / u, u0, u

    def magnification(self, wavelength_nm: float | None = None) -> torch.Tensor:
        """Paraxial transverse magnification m = n u_0 / (n' u'_k) of the object plane (0 at infinity), at
        ``wavelength_nm`` (default: the primary wavelength)."""
        wavelength_nm = self.reference_wavelength_nm if wavelength_nm is None else wavelength_nm
        if math.isinf(self.object_distance_mm):
            return torch.zeros((), dtype=self.dtype)
        _, u0, u = self._finite_axial(wavelength_nm, self.object_distance_mm)
        n = self.geometry.indices(wavelength_nm)
        return n[0] * u0 / (n[-1] * u)

    def image_plane_z(self, wavelength_nm: float) -> torch.Tensor:
        """Paraxial image of the object (at ``object_distance_mm``; the focus at infinity) at ``wavelength_nm``
        (mm from the surface-1 vertex)."""
        g = self.geometry
        return g.vertex_z[-1] + self.paraxial_image_distance_mm(wavelength_nm)

    @property
    def sensor_z(self) -> torch.Tensor:
        """The image plane the lens is focused on (mm from the surface-1 vertex): the paraxial image of
        ``focus_distance_mm`` at the primary wavelength; with ``image_plane='prescription'`` the file's image surface
        (where its designer put the best focus for the file's object distance, as OpticStudio evaluates it),
        moved by the paraxial back-focus shift from that object distance to ``focus_distance_mm``."""
        wl = self.reference_wavelength_nm
        z = self.geometry.vertex_z[-1] + self.paraxial_image_distance_mm(wl, self.focus_distance_mm)
        if self.image_plane == "prescription":
            z = z + (self.prescription_image_distance_mm
                     - self.paraxial_image_distance_mm(wl, self.prescription.object_distance_mm))
        return z

    def image_height_per_tan_mm(self) -> torch.Tensor:
        """Paraxial chief-ray height on the sensor plane per unit tan(field angle) (mm); the EFL when focused at
        infinity, EFL + (back-focus shift) x (paraxial chief-ray slope) otherwise."""
        if math.isinf(self.focus_distance_mm):
            return self.effective_focal_length_mm
        g = self.geometry
        n = g.indices(self.reference_wavelength_nm)
        one = torch.ones((), dtype=self.dtype)
        yc, uc = g._paraxial_trace(-self.ref["ep_z"], one, n)
        return yc[-1] + (self.sensor_z - g.vertex_z[-1]) * uc

    def working_f_number(self) -> torch.Tensor:
        """Paraxial image-space working f-number ``1 / (2 |u'|)`` of the axial object's marginal ray (the f-number
        at infinity); Smith, *Modern Optical Engineering*, ch. 9."""
        if math.isinf(self.object_distance_mm):
            return self.f_number
        d = self.object_distance_mm
        g = self.geometry
        n = g.indices(self.reference_wavelength_nm)
        r = self.ref["epd"] / 2
        u0 = r / (d + self.ref["ep_z"])  # marginal ray: axial object point to the entrance-pupil rim
        _, u = g._paraxial_trace(u0 * d, u0, n)
        return 1.0 / (2 * n[-1] * u.abs())

    def field_angle_deg(self, field: float) -> float:
        f = float(field)
        if not (0.0 <= f <= 1.0 + 1e-9):
            raise TraceError(f"field: {f} is beyond the lens; expected a fraction in [0, 1] of its largest field "
                             f"angle {self.max_field_deg} deg")
        return f * self.max_field_deg

    # --- rays -----------------------------------------------------------------------------------------
    def rays(self, theta_deg: float, px: torch.Tensor, py: torch.Tensor, wavelength_nm: float,
             clip: bool = True, record: bool = False) -> RayBundle:
        """Trace rays of field angle ``theta_deg`` (in the y-z plane) through normalised entrance-pupil points
        ``(px, py)`` (unit circle = paraxial EP at the primary wavelength). Object at infinity: start points lie on
        the plane through the EP centre normal to the rays (a plane wavefront: optical path 0 there). Finite object:
        rays leave the object point ``(0, -(D + z_EP) tan(theta), -D)`` and start (optical path 0) on the sphere
        about it through the EP centre."""
        ref = self.ref
        r = ref["epd"] / 2
        th = math.radians(theta_deg)
        if not math.isinf(self.object_distance_mm):
            d_o = self.object_distance_mm
            q = torch.stack([px * r, py * r, torch.zeros_like(px) + ref["ep_z"]], -1)
            o = torch.zeros_like(q)
            o[..., 1] = -(d_o + ref["ep_z"]) * math.tan(th)
            o[..., 2] = -d_o
            qo = q - o
            dist = torch.linalg.vector_norm(qo, dim=-1)
            d = qo / dist[..., None]
            # start on the sphere about the object point through the EP centre (equal optical path from the
            # object point): q - delta d with delta = |q - o| - R computed without cancellation,
            # |q - o|^2 - R^2 = qx^2 + qy^2 - 2 qy oy, so that far objects keep their OPD precision
            rad = torch.sqrt(o[..., 1] ** 2 + (d_o + ref["ep_z"]) ** 2)
            delta = (q[..., 0] ** 2 + q[..., 1] ** 2 - 2 * q[..., 1] * o[..., 1]) / (dist + rad)
            return self.geometry.trace(q - delta[..., None] * d, d, wavelength_nm, clip=clip, record=record)
        d = torch.stack([torch.zeros_like(px), torch.full_like(px, math.sin(th)), torch.full_like(px, math.cos(th))],
                        -1)
        q = torch.stack([px * r, py * r, torch.zeros_like(px) + ref["ep_z"]], -1)
        c = torch.zeros_like(q)
        c[..., 2] = ref["ep_z"]
        p0 = q - ((q - c) * d).sum(-1, keepdim=True) * d
        return self.geometry.trace(p0, d, wavelength_nm, clip=clip, record=record)

    @staticmethod
    def to_plane(b: RayBundle, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions ``[..., 3]`` where rays cross the plane ``z``, and the signed distance travelled."""
        t = (z - b.position[..., 2]) / b.direction[..., 2]
        return b.position + t[..., None] * b.direction, t

    def chief_ray(self, field: float, wavelength_nm: float, image_z: torch.Tensor | None = None):
        """Chief ray at the paraxial image plane (of ``wavelength_nm`` unless ``image_z``): (point, direction)."""
        theta = self.field_angle_deg(field)
        z0 = torch.zeros(1, dtype=self.dtype)
        b = self.rays(theta, z0, z0, wavelength_nm, clip=False)
        if not bool(b.valid.all()):
            raise TraceError(f"field {field} ({theta:.4g} deg) at {wavelength_nm} nm: the chief ray misses a "
                             f"surface or is totally reflected; the field is beyond the lens")
        z = self.image_plane_z(wavelength_nm) if image_z is None else image_z
        pt, _ = self.to_plane(b, z)
        return pt[0], b.direction[0]

    # --- report quantities ------------------------------------------------------------------------
    def image_height_mm(self, field: float, wavelength_nm: float) -> torch.Tensor:
        return self.chief_ray(field, wavelength_nm)[0][1]

    def distortion_percent(self, field: float, wavelength_nm: float) -> torch.Tensor:
        theta = math.radians(self.field_angle_deg(field))
        y = self.image_height_mm(field, wavelength_nm)
        if theta == 0.0:
            return torch.zeros((), dtype=self.dtype)
        yp = self.effective_focal_length_mm * math.tan(theta)
        return 100.0 * (y - yp) / yp

    def chief_ray_angle_deg(self, field: float, wavelength_nm: float) -> torch.Tensor:
        """Image-space chief-ray angle to the axis (deg), positive when the ray rises towards +y."""
        d = self.chief_ray(field, wavelength_nm)[1]
        return torch.rad2deg(torch.atan2(d[1], d[2]))

    def relative_illumination(self, field: float, wavelength_nm: float, samples: int = 256,
                              method: str = "rimmer") -> torch.Tensor:
        """Relative illumination at ``field``: the irradiance of a uniform Lambertian scene there over the on-axis
        one (same wavelength), on a ``samples`` x ``samples`` pupil grid (an integer >= 16).

        ``method="rimmer"`` (OpticStudio's "Relative Illumination"; M. Rimmer, Proc. SPIE 655, 1986): the projected
        solid angle (area in direction-cosine space) of one object point's vignetted image-space beam. It equals the
        irradiance when that beam comes to a near-point image on the image plane; where it does not, it measures the
        beam's convergence rather than the light on the plane: a plano-convex singlet (f 50 mm, F/5, stop at the
        lens, field-curved) reads 1.095 / 1.227 at 20 / 30 deg where a Monte-Carlo irradiance of the scene gives
        0.796 / 0.550, a near-ideal F/193 lens 1.084 for cos^4 = 0.780 at 20 deg; the bundled aspheric singlet
        (f/1.29, 47 waves RMS at 10 deg) 1.027 for 0.971; corrected lenses agree with the others to 0.3-1 %.

        ``method="flux"``: the light of the scene's directions around the field's, through the unvignetted pupil,
        over the image area the chief ray maps them to on the sensor plane (:attr:`sensor_z`): with theta the field
        angle and y(theta) the chief ray's height there, ``RI = [A(theta) / A(0)] cos(theta) sin(theta) y'(0)^2 / (y
        y')``, A the unvignetted part of the entrance pupil (the beam's cross-section is A cos(theta)), the solid
        angle sin(theta) d(theta) d(phi) over the area y dy d(phi) (conservation of the flux between the scene's
        directions and the image area, with distortion's Jacobian: Reshidko & Sasian, "Role of aberrations in the
        relative illumination of a lens system", Opt. Eng. 55(11) 115105, 2016; cos^4 for a distortion-free lens
        without vignetting, W. J. Smith, *Modern Optical Engineering*, 4th ed., "cos^4 law"). The blur moves light
        to and from the neighbouring points, which the PSF (not this ratio) carries, so this is the gain
        :class:`LensOptics` applies before its PSFs: the singlet above 0.787 / 0.575 at 20 / 30 deg against a Monte-
        Carlo irradiance's 0.796 / 0.550 (at the field's edge the blur, 3.5 mm across, and its centroid's offset
        from the chief ray matter), the F/193 lens cos^4 to 1e-3, the bundled aspheric singlet 0.947 at 10 deg
        (Monte-Carlo 0.971: its coma moves the light's centroid off the chief ray). NaN where the chief ray's height
        stops growing with field (the image folds back, as at the edge of a strongly barrel-distorted wide angle:
        the 100 deg retrofocus of the tests beyond 0.9 of its field), where no such ratio exists. Not
        differentiable: its slope and pupil areas are measured by finite differences and ray counts, so the result
        carries no gradient to the prescription (``"rimmer"`` does).

        Rays that miss a surface or are totally reflected inside the pupil count as vignetted here (the
        marginal-ray check of :func:`lens_report` refuses such a lens): a block that totally reflects 29 % of its
        pupil reads 1.16 (Rimmer). They are not refused because a wide-angle lens traced without ray aiming loses a
        third of its paraxial pupil's rays at full field that way (the 100 deg retrofocus of the tests), where
        aimed rays would pass."""
        _check_pupil_samples(samples, "samples")
        if method not in ("rimmer", "flux"):
            raise ValueError(f"method: expected 'rimmer' or 'flux', got {method!r}")
        if method == "flux":
            return self._flux_illumination([field], wavelength_nm, samples)[0]
        return self._area_ratios(self._beam_solid_angle, [field], wavelength_nm, samples)[0]

    def _area_ratios(self, area, fields, wavelength_nm, samples) -> list[torch.Tensor]:
        """``area(field) / area(0)`` for each of ``fields`` (the on-axis one computed once)."""
        axis = area(0.0, wavelength_nm, samples)
        if float(axis) <= 0:
            raise TraceError(f"relative illumination at {wavelength_nm} nm: no on-axis ray passes the clear "
                             f"apertures")
        return [area(f, wavelength_nm, samples) / axis for f in fields]

    def _flux_illumination(self, fields, wavelength_nm, samples) -> torch.Tensor:
        """The ``method="flux"`` relative illumination at each of ``fields`` ``[F]``: the on-axis pupil area and
        chief-ray slope are computed once (LensOptics asks for a table of fields per wavelength)."""
        slope0 = self._axis_slope_mm(wavelength_nm)
        ratios = self._area_ratios(self._pupil_area, fields, wavelength_nm, samples)
        return torch.stack([r * self._flux_jacobian(f, wavelength_nm, slope0) for r, f in zip(ratios, fields)])

    def _axis_slope_mm(self, wavelength_nm) -> float | None:
        """y'(0), mm per radian of field angle, of the chief ray's height on the sensor plane (None without an
        off-axis field): y is odd in theta, so y(d) / d errs by O(d^2)."""
        rad = math.radians(self.max_field_deg)
        if rad == 0.0:
            return None
        with torch.no_grad():
            return float(self.chief_ray(_FLUX_STEP, wavelength_nm, image_z=self.sensor_z)[0][1]) / (_FLUX_STEP * rad)

    def _pupil_area(self, field, wavelength_nm, samples):
        """The unvignetted part of the entrance pupil's grid (normalised units) for ``field``."""
        theta = self.field_angle_deg(field)
        px, py, inside = pupil_grid(samples, self.dtype)
        with torch.no_grad():
            b = self.rays(theta, px[inside], py[inside], wavelength_nm, clip=True)
        return b.valid.sum().to(self.dtype) * (2.0 / samples) ** 2

    def _flux_jacobian(self, field, wavelength_nm, slope0: float | None = None) -> torch.Tensor:
        """``cos(theta) sin(theta) y'(0)^2 / (y y')`` of the chief ray's height y(theta) on the sensor plane (1 on
        axis); y' by central differences of 1e-4 of the field (y is odd in theta, so a step below 0 is read through
        the axis; one-sided, second order, at the field's edge). NaN where y' <= 0 (the image folds back: a chief
        ray's height no longer grows with field, as at the edge of a strongly barrel-distorted wide angle), where
        no flux ratio exists. ``slope0``: y'(0) (:meth:`_axis_slope_mm`), computed here when not given."""
        f = float(field)
        rad = math.radians(self.max_field_deg)
        if f == 0.0 or rad == 0.0:
            return torch.ones((), dtype=self.dtype)
        z = self.sensor_z
        d = _FLUX_STEP

        def y(fr: float) -> float:
            if fr < 0:
                return -y(-fr)
            with torch.no_grad():
                return float(self.chief_ray(fr, wavelength_nm, image_z=z)[0][1])

        y0 = self._axis_slope_mm(wavelength_nm) if slope0 is None else slope0
        if f + d <= 1.0:
            dy = (y(f + d) - y(f - d)) / (2 * d * rad)
        else:
            dy = (3 * y(f) - 4 * y(f - d) + y(f - 2 * d)) / (2 * d * rad)
        th = f * rad
        yf = y(f)
        if not (dy > 0 and yf > 0):
            return torch.tensor(math.nan, dtype=self.dtype)
        return torch.tensor(math.cos(th) * math.sin(th) * y0 * y0 / (yf * dy), dtype=self.dtype)

    def _beam_solid_angle(self, field, wavelength_nm, samples):
        theta = self.field_angle_deg(field)
        px, py, inside = pupil_grid(samples, self.dtype)
        px, py = px[inside], py[inside]
        h = 1e-5
        b = self.rays(theta, px, py, wavelength_nm, clip=True)
        bx = self.rays(theta, torch.stack([px + h, px - h]), torch.stack([py, py]), wavelength_nm, clip=False)
        by = self.rays(theta, torch.stack([px, px]), torch.stack([py + h, py - h]), wavelength_nm, clip=False)
        dl_dx = (bx.direction[0, :, 0] - bx.direction[1, :, 0]) / (2 * h)
        dm_dx = (bx.direction[0, :, 1] - bx.direction[1, :, 1]) / (2 * h)
        dl_dy = (by.direction[0, :, 0] - by.direction[1, :, 0]) / (2 * h)
        dm_dy = (by.direction[0, :, 1] - by.direction[1, :, 1]) / (2 * h)
        det = (dl_dx * dm_dy - dl_dy * dm_dx).abs()
        return torch.where(b.valid, det, torch.zeros_like(det)).sum() * (2.0 / samples) ** 2

    # --- pupil function, PSF, MTF --------------------------------------------------------------------
    def pupil_function(self, field: float, wavelength_nm: float, samples: int = 128,
                       image_z: torch.Tensor | None = None) -> dict:
        """Pupil function on a ``samples x samples`` grid over the entrance pupil (rows = y = field direction).

        Returns a dict: ``pupil`` (complex ``[N, N]``), ``opd_waves`` (0 outside the beam), ``valid``,
        ``cutoff_cy_mm`` (tangential, sagittal) and ``image_point`` (chief ray at ``image_z``, default the
        sensor plane :attr:`sensor_z`: the primary wavelength's paraxial focus of ``focus_distance_mm``).
        """
        theta = self.field_angle_deg(field)
        zi = self.sensor_z if image_z is None else image_z
        par = self.paraxial(wavelength_nm)
        ipt, _ = self.chief_ray(field, wavelength_nm, image_z=zi)
        z0 = torch.zeros(1, dtype=self.dtype)
        chief = self.rays(theta, z0, z0, wavelength_nm, clip=False)
        # reference sphere: centre = chief ray's image point, through the chief ray at the paraxial exit pupil
        g = self.geometry
        xp = par["xp_z"]
        if torch.isfinite(xp) and abs(float(xp.detach())) < 1e6:
            e, _ = self.to_plane(chief, g.vertex_z[-1] + xp)
            radius = torch.linalg.vector_norm(e[0] - ipt)
        else:
            radius = None
        px, py, inside = pupil_grid(samples, self.dtype)
        b = self.rays(theta, px, py, wavelength_nm, clip=True)
        valid = b.valid & inside
        n_img = par["n_image"]

        def opl_to_sphere(bb: RayBundle):
            if radius is None:  # telecentric image space: reference plane through the chief ray, normal to it
                dc = chief.direction[0]
                t = ((ipt - bb.position) * dc).sum(-1) / (bb.direction * dc).sum(-1)
                return bb.opl + n_img * t
            rel = bb.position - ipt
            bq = (rel * bb.direction).sum(-1)
            cq = (rel * rel).sum(-1) - radius * radius
            disc = bq * bq - cq
            disc = torch.where(disc > 0, disc, torch.zeros_like(disc))
            return bb.opl + n_img * (-bq - torch.sqrt(disc))

        if not bool(valid.any()):
            raise TraceError(f"field {field} ({theta:.4g} deg) at {wavelength_nm} nm: every ray of the pupil misses "
                             f"the lens's clear apertures (fully vignetted); no PSF/MTF")
        opl = opl_to_sphere(b)
        opl_c = opl_to_sphere(chief)[0]
        wl_mm = wavelength_nm * 1e-6
        opd_w = torch.where(valid, (opl - opl_c) / wl_mm, torch.zeros_like(opl))
        phase = 2 * math.pi * opd_w
        pupil = torch.polar(valid.to(self.dtype), phase)
        # frequency scale: real marginal rays' direction cosines (apertures ignored so they always exist)
        one = torch.ones(2, dtype=self.dtype)
        mt = self.rays(theta, 0 * one, torch.tensor([1.0, -1.0], dtype=self.dtype), wavelength_nm, clip=False)
        ms = self.rays(theta, torch.tensor([1.0, -1.0], dtype=self.dtype), 0 * one, wavelength_nm, clip=False)
        if not bool(mt.valid.all() & ms.valid.all()):
            raise TraceError(f"field {field} ({theta:.4g} deg) at {wavelength_nm} nm: a marginal ray of the paraxial "
                             f"entrance pupil misses a surface, so the MTF frequency scale is undefined")
        cut_t = n_img * (mt.direction[0, 1] - mt.direction[1, 1]).abs() / wl_mm
        cut_s = n_img * (ms.direction[0, 0] - ms.direction[1, 0]).abs() / wl_mm
        orient = (1.0 if float(mt.direction[0, 1] - mt.direction[1, 1]) >= 0 else -1.0,
                  1.0 if float(ms.direction[0, 0] - ms.direction[1, 0]) >= 0 else -1.0)
        return {"pupil": pupil, "opd_waves": opd_w, "valid": valid, "cutoff_cy_mm": (cut_t, cut_s),
                "orientation": orient, "image_point": ipt}

    def sampled_pupil(self, field, wavelength_nm, samples=128, image_z=None, max_samples: int = 512,
                      max_step_waves: float = 0.25) -> dict:
        """:meth:`pupil_function` on a grid fine enough for the wavefront: the grid is doubled (from
        ``samples`` up to ``max_samples``) until neighbouring samples differ by at most ``max_step_waves``
        (the sampling criterion of the FFT PSF; OpticStudio warns at the same condition)."""
        n = int(samples)
        while True:
            pf = self.pupil_function(field, wavelength_nm, n, image_z)
            w, v = pf["opd_waves"], pf["valid"]
            step = 0.0
            for dim in (0, 1):
                both = v.narrow(dim, 1, n - 1) & v.narrow(dim, 0, n - 1)
                dw = (w.narrow(dim, 1, n - 1) - w.narrow(dim, 0, n - 1)).abs()
                if both.any():
                    step = max(step, float(dw[both].max()))
            if step <= max_step_waves or 2 * n > max_samples:
                pf["samples"] = n
                pf["max_step_waves"] = step
                return pf
            # jump straight to the grid the measured slope needs (powers of two above n)
            need = n * 2 ** math.ceil(math.log2(step / max_step_waves))
            n = int(min(need, max_samples if max_samples >= 2 * n else n))

    def otf_grid(self, field, wavelength_nm, samples=128, image_z=None, max_samples: int = 512):
        """OTF on the pupil-shift grid (``[2N, 2N]``, DC at [0, 0]) and the pupil data; shift k along rows is
        the tangential frequency k / N * cutoff_t (N = ``pf['samples']``, adapted to the wavefront)."""
        pf = self.sampled_pupil(field, wavelength_nm, samples, image_z, max_samples=max_samples)
        samples = pf["samples"]
        p = pf["pupil"]
        nn_ = 2 * samples
        f = torch.fft.fft2(p, s=(nn_, nn_))
        psf = f.real ** 2 + f.imag ** 2
        otf = torch.fft.ifft2(psf)
        return otf / otf[0, 0].real, pf

    def mtf(self, field: float, wavelength_nm: float, frequencies_cy_mm, samples: int = 128):
        """Tangential and sagittal diffraction MTF at ``frequencies_cy_mm`` (image on :attr:`sensor_z`)."""
        otf, pf = self.otf_grid(field, wavelength_nm, samples)
        samples = pf["samples"]
        mt = otf[:, 0].abs()
        ms = otf[0, :].abs()
        cut_t, cut_s = pf["cutoff_cy_mm"]
        out = []
        for m, cut in ((mt, cut_t), (ms, cut_s)):
            vals = []
            for nu in frequencies_cy_mm:
                # the position on the grid stays a tensor: the cutoff moves with the lens (its curvatures), and
                # read as a float it left that share out of the MTF's gradient (-4.23 for -1.88, no error)
                k = float(nu) / cut * samples
                if float(k.detach()) >= samples:
                    vals.append(torch.zeros((), dtype=self.dtype))
                    continue
                k0 = int(math.floor(float(k.detach())))
                w = k - k0
                vals.append((1 - w) * m[k0] + w * m[k0 + 1])
            out.append(torch.stack(vals))
        return out[0], out[1]


#: the field step (fraction of the largest field) of the flux relative illumination's derivatives
_FLUX_STEP = 1e-4


def pupil_grid(samples: int, dtype=torch.float64) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The ``samples`` x ``samples`` grid over the normalised entrance pupil (cell centres, rows = y): ``(px, py,
    inside)``, ``inside`` the unit disc."""
    u = (torch.arange(samples, dtype=dtype) - (samples - 1) / 2) * (2.0 / samples)
    py, px = torch.meshgrid(u, u, indexing="ij")
    return px, py, px * px + py * py <= 1.0


#: Pupil grid (samples per side) accepted by :func:`lens_report`: at least 16 (a coarser grid has too few samples
#: across the pupil for its autocorrelation to be an MTF), at most 1024 (the FFT grid is 2N x 2N complex).
PUPIL_SAMPLES_RANGE = (16, 1024)


def _values(v, name: str, ok, expected: str, error=ValueError) -> list[float]:
    try:
        vals = [float(x) for x in v]
    except (TypeError, ValueError):
        raise error(f"{name}: expected a list of numbers, got {v!r}") from None
    bad = [x for x in vals if not ok(x)]
    if not vals or bad:
        raise error(f"{name}: expected {expected}, got {bad or vals}")
    return vals


#: image planes of a lens (:class:`LensAnalysis` ``image_plane``): the primary wavelength's paraxial focus, or the
#: prescription's own image surface
IMAGE_PLANES = ("paraxial", "prescription")


def _check_pupil_samples(n, name: str, top: float = math.inf) -> int:
    """A pupil grid's samples per side: an integer in [16, top] (1 or 2 gave a relative illumination of 0.943 and
    0.939 for the true 0.939 by luck; 2.7 was truncated), else a ValueError naming ``name``."""
    lo = PUPIL_SAMPLES_RANGE[0]
    if not is_integer(n) or not lo <= n <= top:
        raise ValueError(f"{name}: expected an integer in [{lo}, {top}], got {n!r}")
    return int(n)


def lens_report(lens, fields=(0.0, 0.7, 1.0), wavelengths_nm=None, frequencies_cy_mm=(20.0, 40.0, 80.0),
                pupil_samples: int = 128, ri_samples: int = 256) -> dict:
    """The ``lens-report`` JSON object (see the module docstring for the conventions).

    Args:
        fields: fractions in [0, 1] of the lens's largest field angle.
        wavelengths_nm: default: the prescription's wavelengths.
        frequencies_cy_mm: MTF frequencies (finite, >= 0).
        pupil_samples: pupil grid of the FFT MTF (:data:`PUPIL_SAMPLES_RANGE`; adapted upwards to the wavefront).
        ri_samples: pupil grid of the relative-illumination integral (>= 16).

    Each row's ``relative_illumination`` is Rimmer's (OpticStudio's), ``relative_illumination_flux`` the scene's
    flux over the chief ray's image area on the sensor plane (what ``LensOptics`` renders;
    :meth:`LensAnalysis.relative_illumination`): where they differ by more than a percent or two, the beams are not
    focused on the plane (field curvature, strong aberrations) and the flux one is the image's.

    Raises:
        ValueError: an argument out of range (the message starts with its name).
    """
    a = lens if isinstance(lens, LensAnalysis) else LensAnalysis(lens)
    fields = _values(fields, "fields", lambda f: 0.0 <= f <= 1.0,
                     f"fractions in [0, 1] of the largest field angle ({a.max_field_deg} deg; more is beyond the "
                     f"lens)", TraceError)
    if wavelengths_nm is None:
        wavelengths_nm = a.prescription.wavelengths_nm
    wavelengths_nm = _values(wavelengths_nm, "wavelengths_nm", lambda w: math.isfinite(w) and w > 0,
                             "finite wavelengths > 0 nm")
    frequencies_cy_mm = _values(frequencies_cy_mm, "frequencies_cy_mm", lambda v: math.isfinite(v) and v >= 0,
                                "finite frequencies >= 0 cycles/mm")
    _check_pupil_samples(pupil_samples, "pupil_samples", PUPIL_SAMPLES_RANGE[1])
    _check_pupil_samples(ri_samples, "ri_samples")
    rows = []
    with torch.no_grad():
        for f in fields:
            for wl in wavelengths_nm:
                mt, ms = a.mtf(f, wl, frequencies_cy_mm, pupil_samples)
                rows.append({
                    "field": float(f), "wavelength_nm": float(wl),
                    "image_height_mm": float(a.image_height_mm(f, wl)),
                    "distortion_percent": float(a.distortion_percent(f, wl)),
                    "relative_illumination": float(a.relative_illumination(f, wl, ri_samples)),
                    "relative_illumination_flux": float(a.relative_illumination(f, wl, ri_samples, method="flux")),
                    "chief_ray_angle_deg": float(a.chief_ray_angle_deg(f, wl)),
                    "mtf_tangential": [float(v) for v in mt],
                    "mtf_sagittal": [float(v) for v in ms],
                })
    for r in rows:
        for k, v in r.items():
            vals = v if isinstance(v, list) else [v]
            if any(not math.isfinite(x) for x in vals):
                raise TraceError(f"{a.prescription.name or 'lens'}: non-finite {k} at field {r['field']}, "
                                 f"{r['wavelength_nm']} nm (rays missing a surface or the image?)")
    return {"effective_focal_length_mm": float(a.effective_focal_length_mm), "f_number": float(a.f_number),
            "max_field_deg": float(a.max_field_deg), "image_plane": a.image_plane, "rows": rows}
