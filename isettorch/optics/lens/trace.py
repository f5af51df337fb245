"""A small sequential real-ray and paraxial tracer in torch (float64, batched, differentiable).

Surfaces: spheres, conics and even aspheres, rotationally symmetric about z, each at its vertex on the axis.
Real rays: intersection of a ray with the conic in closed form (Welford, *Aberrations of Optical Systems*, 1986,
sec. 4.4: transfer to the vertex tangent plane, then the stable root of the quadric), refined by Newton's method on
the aspheric terms; refraction by the vector Snell law n' (D' x N) = n (D x N). Paraxial quantities from the
y-nu trace (Smith, *Modern Optical Engineering*, 4th ed., ch. 3): n'u' = nu - y c (n' - n), y+ = y + t u'.
Distances in mm. The tracer's parameters (curvatures, thicknesses) are tensors: gradients flow to them.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from .glass import GlassError, refractive_index
from .prescription import DATA_DIR, Prescription

__all__ = ["LensGeometry", "RayBundle", "TraceError"]


class TraceError(ValueError):
    """Rays that cannot be traced (missing a surface, total internal reflection, field beyond the lens)."""


class RayBundle:
    """Rays after a trace: ``position``, ``direction`` (unit, ``[..., 3]``), optical path ``opl`` and ``valid``."""

    def __init__(self, position, direction, opl, valid, heights=None):
        self.position, self.direction, self.opl, self.valid = position, direction, opl, valid
        self.heights = heights  # radial height at each surface [S, ...] (when traced with record=True)


class LensGeometry:
    """The lens surfaces of a :class:`Prescription` as tensors.

    Args:
        prescription: the lens.
        curvature_per_mm: optional tensor ``[S]`` replacing the lens surfaces' curvatures (e.g. an
            ``nn.Parameter`` to fit); S = number of lens surfaces (object and image excluded).
    """

    def __init__(self, prescription: Prescription, curvature_per_mm: torch.Tensor | None = None,
                 dtype=torch.float64, device=None):
        self.prescription = p = prescription
        lens = p.surfaces[1:-1]
        self.n_surfaces = len(lens)
        kw = {"dtype": dtype, "device": device}
        if curvature_per_mm is None:
            curvature_per_mm = torch.tensor([s.curvature_per_mm for s in lens], **kw)
        if curvature_per_mm.shape != (len(lens),):
            raise ValueError(f"curvature_per_mm: expected shape ({len(lens)},), got {tuple(curvature_per_mm.shape)}")
        if not bool(torch.isfinite(curvature_per_mm.detach()).all()):  # (NaN gave a NaN focal length)
            raise ValueError(f"curvature_per_mm: expected finite curvatures, got "
                             f"{curvature_per_mm.detach().tolist()}")
        self.curvature = curvature_per_mm
        self.thickness = torch.tensor([s.thickness_mm for s in lens], **kw)
        if not torch.isfinite(self.thickness[:-1]).all():
            raise TraceError(f"{p.name}: infinite thickness inside the lens")
        self.vertex_z = torch.cat([torch.zeros(1, **kw), torch.cumsum(self.thickness[:-1], 0)])
        self.conic = torch.tensor([s.conic for s in lens], **kw)
        na = max([len(s.aspheric) for s in lens] + [0])
        self.aspheric = torch.tensor([list(s.aspheric) + [0.0] * (na - len(s.aspheric)) for s in lens],
                                     **kw).reshape(len(lens), na)
        self.aperture = torch.tensor([math.inf if s.aperture_mm is None else s.aperture_mm for s in lens], **kw)
        self.aperture_min = torch.tensor([s.aperture_min_mm for s in lens], **kw)
        self.materials = [s.material for s in p.surfaces[:-1]]  # medium before lens surface i (0 = object space)
        self.stop = p.stop_index - 1
        # OpticStudio without ray aiming: rays fill the paraxial entrance pupil; the stop surface does not clip
        self.aperture[self.stop] = math.inf
        self.aperture_min[self.stop] = 0.0
        self.dtype, self.device = dtype, device
        self._cache: dict = {}

    # --- media --------------------------------------------------------------------------------------
    def indices(self, wavelength_nm: float) -> list[float]:
        """Refractive indices of the media: object space, then after each lens surface (``S + 1`` values)."""
        cats = self.prescription.catalogs
        out = []
        for i, m in enumerate(self.materials):
            try:
                out.append(refractive_index(m, float(wavelength_nm), cats))
            except GlassError as e:
                where = self.prescription.name
                source = self.prescription.source  # a .zmx file's path (a YAML lens's is a citation; a bundled
                # lens is named by its name)
                if source and source != where and Path(source).is_file() and Path(source).parent != DATA_DIR:
                    where = f"{where} ({source})"
                raise GlassError(f"{where}, the medium after surface {i}: {e}") from None
        return out

    # --- paraxial -----------------------------------------------------------------------------------
    def _paraxial_trace(self, y0, u0, n, upto=None):
        """y-nu trace from the surface-1 vertex plane in object space; returns heights ``[S]`` and the last u'."""
        y, nu = y0, n[0] * u0
        ys = []
        last = self.n_surfaces if upto is None else upto + 1
        for i in range(last):
            c = self.curvature[i] + (2 * self.aspheric[i, 0] if self.aspheric.shape[1] else 0.0)
            ys.append(y)
            nu = nu - y * c * (n[i + 1] - n[i])
            if i + 1 < last:
                y = y + self.thickness[i] * nu / n[i + 1]
        return ys, nu / n[last]

    def paraxial(self, wavelength_nm: float) -> dict:
        """Paraxial data at one wavelength (mm): ``efl``, ``bfl`` (last vertex -> focus), ``ep_z`` (entrance
        pupil, from the surface-1 vertex), ``epd``, ``xp_z`` (exit pupil, from the last vertex), ``n_image``."""
        n = self.indices(wavelength_nm)
        one = torch.ones((), dtype=self.dtype, device=self.device)
        ys, u = self._paraxial_trace(one, 0 * one, n)
        if float(u.detach()) == 0:
            raise TraceError(f"{self.prescription.name}: afocal lens (no paraxial focus)")
        efl = -1.0 / (n[-1] * u)
        bfl = -ys[-1] / u
        a = self._paraxial_trace(one, 0 * one, n, upto=self.stop)[0][-1]
        b = self._paraxial_trace(0 * one, one, n, upto=self.stop)[0][-1]
        ep_z = b / a
        if self.prescription.float_by_stop:
            # float by stop size: DIAM of the stop is a semi-diameter (Zemax); EPD = 2 semi / (stop/EP height)
            epd = 2 * self.prescription.surfaces[self.stop + 1].semi_diameter_mm / a.abs()
        elif self.prescription.image_f_number is not None:
            # image-space F/# (OpticStudio's FNUM aperture): EPD = EFL / F# with the EFL at the primary wavelength,
            # the same pupil for every wavelength
            primary = self.prescription.primary_wavelength_nm
            efl_p = efl if float(wavelength_nm) == float(primary) else self.paraxial(primary)["efl"]
            epd = efl_p.abs() / self.prescription.image_f_number
        else:
            epd = self.prescription.entrance_pupil_diameter_mm * one
        yc, uc = self._paraxial_trace(-ep_z, one, n)
        xp_z = -yc[-1] / uc if float(uc.detach()) != 0 else torch.full_like(one, math.inf)
        return {"efl": efl, "bfl": bfl, "ep_z": ep_z, "epd": epd, "xp_z": xp_z, "n": n, "n_image": n[-1]}

    # --- real rays ----------------------------------------------------------------------------------
    def _sag_terms(self, i, rho2):
        """Sag z(rho^2) and dz/d(rho^2) of surface i (Zemax STANDARD/EVENASPH), plus the domain mask."""
        c, k = self.curvature[i], self.conic[i]
        arg = 1 - (1 + k) * c * c * rho2
        ok = arg > 0
        sq = torch.sqrt(torch.where(ok, arg, torch.ones_like(arg)))
        z = c * rho2 / (1 + sq)
        dz = c / (2 * sq)
        for j in range(self.aspheric.shape[1]):
            a = self.aspheric[i, j]
            if float(a) != 0.0 or a.requires_grad:
                z = z + a * rho2 ** (j + 1)
                dz = dz + a * (j + 1) * rho2 ** j
        return z, dz, ok

    def trace(self, position, direction, wavelength_nm: float, clip: bool = True, n=None,
              record: bool = False) -> RayBundle:
        """Trace rays ``position, direction [..., 3]`` (object space, z from the surface-1 vertex) through the
        lens. Returns the rays just after the last surface, with the optical path from the start points.

        ``valid`` is False for rays that miss a surface, are totally reflected or (``clip``) fall outside a
        clear aperture; their values stay finite.
        """
        n = self.indices(wavelength_nm) if n is None else n
        p, d = position, direction
        opl = torch.zeros(p.shape[:-1], dtype=p.dtype, device=p.device)
        valid = torch.ones(p.shape[:-1], dtype=torch.bool, device=p.device)
        has_asph = self.aspheric.shape[1] > 0
        heights = []
        for i in range(self.n_surfaces):
            zv = self.vertex_z[i]
            px, py, pz = p[..., 0], p[..., 1], p[..., 2] - zv
            dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
            t0 = -pz / dz
            x0, y0 = px + t0 * dx, py + t0 * dy
            c, k = self.curvature[i], self.conic[i]
            # quadric c(x^2+y^2) + c(1+k) z^2 - 2z = 0 from (x0, y0, 0): A t^2 + 2 b t + C = 0
            a_ = c * (dx * dx + dy * dy + (1 + k) * dz * dz)
            b_ = c * (x0 * dx + y0 * dy) - dz
            c_ = c * (x0 * x0 + y0 * y0)
            disc = b_ * b_ - a_ * c_
            # (a ray grazing the sphere, disc 0, is a miss: sqrt's derivative there was inf, and NaN in a masked loss)
            ok = disc > 0
            t1 = c_ / (-b_ + torch.sqrt(torch.where(ok, disc, torch.ones_like(disc))))
            if has_asph:
                for _ in range(12):  # Newton on f(t) = z(t) - sag(rho^2(t))
                    x, y, z = x0 + t1 * dx, y0 + t1 * dy, t1 * dz
                    s, ds, okd = self._sag_terms(i, x * x + y * y)
                    f = z - s
                    fp = dz - ds * 2 * (x * dx + y * dy)
                    t1 = t1 - f / torch.where(fp.abs() > 1e-12, fp, torch.ones_like(fp))
            x, y = x0 + t1 * dx, y0 + t1 * dy
            rho2 = x * x + y * y
            if record:
                heights.append(torch.sqrt(rho2))
            sag, ds, okd = self._sag_terms(i, rho2)
            # the point must lie on the surface: the quadric's root on the sphere's far side (a wide field through a
            # strong meniscus: 2.4 mm off it) and an asphere's unconverged Newton steps (up to 262 mm off) were
            # taken as hits, refracted by the surface's normal there
            zl = t1 * dz
            eps = torch.finfo(zl.dtype).eps
            on = (zl - sag).abs() <= 1e3 * eps * (1 + zl.abs() + sag.abs() + rho2.sqrt())
            ok = ok & okd & on
            t = t0 + t1
            opl = opl + n[i] * t
            p = torch.stack([x, y, zv + t1 * dz], -1)
            if clip:
                ok = ok & (rho2 <= self.aperture[i] ** 2) & (rho2 >= self.aperture_min[i] ** 2)
            nrm = torch.stack([-2 * x * ds, -2 * y * ds, torch.ones_like(ds)], -1)
            nrm = nrm / torch.linalg.vector_norm(nrm, dim=-1, keepdim=True)
            cos_i = (d * nrm).sum(-1)
            mu = n[i] / n[i + 1]
            kk = 1 - mu * mu * (1 - cos_i * cos_i)
            ok = ok & (kk > 0)
            cos_t = torch.sqrt(torch.where(kk > 0, kk, torch.ones_like(kk)))
            d = mu * d + (cos_t - mu * cos_i)[..., None] * nrm
            valid = valid & ok
        return RayBundle(p, d, opl, valid, torch.stack(heights) if record else None)
