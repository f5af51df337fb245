"""Field- and wavelength-dependent PSFs of a lens on an optical-image grid, and their low-rank decomposition.

The OTF of each (field, wavelength) comes from :meth:`LensAnalysis.otf_grid` (FFT of the pupil function); a PSF at
image azimuth phi is the field-along-+y PSF rotated by phi, done exactly in the frequency domain
(OTF_phi(nu) = OTF_0(R^-1 nu)), then sampled on the optical image's pitch by an inverse DFT (band-limited to the
grid's Nyquist frequency, as the shift-invariant optics' OTF blur is).
Low-rank (eigen-PSF) form: PSF(x; s) ~ sum_j w_j(s) e_j(x) from the SVD of the PSF set (Lauer, "Deconvolution with
a spatially-variant PSF", Proc. SPIE 4847, 2002; Flicker & Rigaut, JOSA A 22, 2005), applied as
out = sum_j e_j * (w_j . in) (each source spreads with its own PSF).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .analysis import LensAnalysis

__all__ = ["otf_sampler", "psf_on_grid", "chief_ray_heights_mm", "spot_radius_mm"]


def otf_sampler(analysis: LensAnalysis, field: float, wavelength_nm: float, samples: int = 64,
                max_samples: int = 256):
    """A function ``(nu_t, nu_s) -> complex OTF`` (cycles/mm along the field direction and across it), standard
    convention OTF(nu) = integral psf(x) exp(-2 pi i nu x) dx, zero beyond the pupil's autocorrelation support."""
    with torch.no_grad():
        otf, pf = analysis.otf_grid(field, wavelength_nm, samples, max_samples=max_samples)
        n = pf["samples"]
        cut_t, cut_s = (float(c) for c in pf["cutoff_cy_mm"])
        # orientation: pupil +y maps to image-space direction cosine M with the sign of dM/dpy
        sign_t, sign_s = pf["orientation"]
    grid = torch.fft.fftshift(otf)  # DC at [n, n] of a [2n, 2n] grid
    img = torch.stack([grid.real, grid.imag])[None].to(torch.float64)  # [1, 2, 2n, 2n]

    def sample(nu_t: torch.Tensor, nu_s: torch.Tensor) -> torch.Tensor:
        kt = sign_t * nu_t / cut_t * n
        ks = sign_s * nu_s / cut_s * n
        inside = (kt.abs() < n) & (ks.abs() < n)
        gy = (kt + n) / (2 * n - 1) * 2 - 1
        gx = (ks + n) / (2 * n - 1) * 2 - 1
        g = torch.stack([gx, gy], -1).reshape(1, 1, -1, 2).to(torch.float64)
        v = F.grid_sample(img, g, mode="bilinear", padding_mode="zeros", align_corners=True)[0, :, 0]
        out = torch.complex(v[0], v[1]).reshape(nu_t.shape)
        return torch.where(inside, out, torch.zeros_like(out))

    return sample


def psf_on_grid(sampler, azimuths_rad: torch.Tensor, dx_mm: float, size: int) -> torch.Tensor:
    """PSFs ``[A, size, size]`` (sum 1, centre at ``size // 2``) rotated to each azimuth (angle of the field
    direction from +y towards +x), sampled with pitch ``dx_mm``; rows are y, columns x."""
    f = torch.fft.fftfreq(size, d=dx_mm, dtype=torch.float64)
    fy, fx = torch.meshgrid(f, f, indexing="ij")
    out = []
    for phi in azimuths_rad.tolist():
        ux, uy = math.sin(phi), math.cos(phi)  # radial (tangential) direction
        vx, vy = math.cos(phi), -math.sin(phi)  # perpendicular (sagittal) direction
        otf = sampler(fx * ux + fy * uy, fx * vx + fy * vy)
        psf = torch.fft.fftshift(torch.fft.ifft2(otf).real)
        psf = psf.clamp_min(0)
        out.append(psf / psf.sum())
    return torch.stack(out)


def chief_ray_heights_mm(analysis: LensAnalysis, fields: torch.Tensor, wavelength_nm: float) -> torch.Tensor:
    """Chief-ray image heights (mm) on the sensor plane (587.6 nm paraxial focus) for field fractions ``fields``."""
    z = analysis.sensor_z
    out = []
    for f in fields.tolist():
        out.append(analysis.chief_ray(f, wavelength_nm, image_z=z)[0][1])
    return torch.stack(out)


def spot_radius_mm(analysis: LensAnalysis, field: float, wavelength_nm: float, samples: int = 24) -> float:
    """Largest distance of a traced (unvignetted) ray from the chief ray on the sensor plane (mm)."""
    theta = analysis.field_angle_deg(field)
    u = (torch.arange(samples, dtype=torch.float64) - (samples - 1) / 2) * (2.0 / samples)
    py, px = torch.meshgrid(u, u, indexing="ij")
    m = px * px + py * py <= 1
    z = analysis.sensor_z
    with torch.no_grad():
        b = analysis.rays(theta, px[m], py[m], wavelength_nm)
        pts, _ = analysis.to_plane(b, z)
        c, _ = analysis.chief_ray(field, wavelength_nm, image_z=z)
    d = torch.linalg.vector_norm(pts[..., :2] - c[:2], dim=-1)[b.valid]
    return float(d.max()) if d.numel() else 0.0
