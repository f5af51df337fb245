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

__all__ = ["TableOTF", "otf_sampler", "psf_on_grid", "chief_ray_heights_mm", "spot_radius_mm"]


class TableOTF:
    """The OTF of one (field, wavelength) of a lens: ``(nu_t, nu_s) -> complex OTF`` (cycles/mm along the field
    direction and across it), standard convention OTF(nu) = integral psf(x) exp(-2 pi i nu x) dx, zero beyond the
    pupil's autocorrelation support.

    :meth:`LensAnalysis.otf_grid` gives the OTF at integer pupil shifts (the autocorrelation of the sampled pupil,
    ``[2N, 2N]``); between them the OTF is the trigonometric interpolant: the Fourier transform of the one period of
    PSF ``q`` that table is the DFT of (``N`` pupil samples: a window of ``N lambda N_f``). Bilinear interpolation of
    the table itself (before 2026-11-30) was the transform of that PSF repeated every ``N lambda N_f`` (the pupil's
    samples act as a grating): ghost light, a kernel L1 error of 3-5 % at 64 samples on the Cooke triplet.

    Evaluated as a non-uniform FFT: ``q`` (cut to a disc, :meth:`table`) is divided by the bilinear kernel's
    transform (``sinc^2`` per axis), zero-padded to ``Z = 4`` times the disc's diameter or the table's period (up to
    1024 points), transformed, and that dense table interpolated bilinearly: the division undoes the interpolation's
    envelope on the PSF, and its repeats move that far away, with weight of order ``(PSF width / padded size)^2``.
    """

    def __init__(self, analysis: LensAnalysis, field: float, wavelength_nm: float, samples: int = 64,
                 max_samples: int = 256):
        with torch.no_grad():
            otf, pf = analysis.otf_grid(field, wavelength_nm, samples, max_samples=max_samples)
        n = pf["samples"]
        cut_t, cut_s = (float(c) for c in pf["cutoff_cy_mm"])
        # orientation: pupil +y maps to image-space direction cosine M with the sign of dM/dpy
        sign_t, sign_s = pf["orientation"]
        self.n, self.cut_t, self.cut_s, self.sign_t, self.sign_s = n, cut_t, cut_s, sign_t, sign_s
        self.zoom = 4
        # otf[k] = sum_m q[m] exp(+2 pi i k m / 2N) (otf_grid's table is an inverse DFT): q, at signed m
        self.q = torch.fft.fft2(otf.to(torch.complex128)) / (2 * n) ** 2
        m = torch.fft.fftfreq(2 * n, d=1.0 / (2 * n), dtype=torch.float64)  # 0, 1, ..., N-1, -N, ..., -1
        self.mt, self.ms = torch.meshgrid(m, m, indexing="ij")  # rows: tangential shift, columns: sagittal
        # k_t = sign_t nu_t N / cut_t, so k_t m_t / 2N = nu_t T with T = sign_t m_t / (2 cut_t) (mm); S likewise
        self.t_mm, self.s_mm = sign_t * self.mt / (2 * cut_t), sign_s * self.ms / (2 * cut_s)
        self._tables: dict = {}

    def table(self, radius_mm: float = math.inf) -> tuple[torch.Tensor, int]:
        """The OTF of the PSF cut to the disc of ``radius_mm`` (light beyond it left out, not wrapped into a
        kernel's window) on a dense shift grid: ``([1, 2, L, L]`` real and imaginary parts, DC at ``L / 2``,
        ``L``), ``L / 2N`` grid steps per table shift; cached. ``L`` is ``Z`` times the disc's diameter in PSF
        samples (at most the table's period): a small kernel window costs a small transform."""
        key = round(radius_mm, 9) if math.isfinite(radius_mm) else math.inf
        if key not in self._tables:
            n = self.n
            reach = n if not math.isfinite(radius_mm) else min(
                n, int(math.ceil(radius_mm * 2 * max(self.cut_t, self.cut_s))) + 1)  # in PSF samples
            # at least the period's, up to 1024 points: the repeats' weight falls as (PSF width / size)^2
            size = max(2 * reach * self.zoom, min(2 * n * self.zoom, 1024))
            q = torch.where(self.t_mm**2 + self.s_mm**2 <= radius_mm**2, self.q, torch.zeros_like(self.q))
            q = q / (torch.sinc(self.mt / size) * torch.sinc(self.ms / size)) ** 2  # the bilinear envelope, undone
            inside = (self.mt.abs() <= reach) & (self.ms.abs() <= reach)
            grid = torch.zeros(size, size, dtype=torch.complex128)
            grid[self.mt[inside].long() % size, self.ms[inside].long() % size] = q[inside]
            dense = torch.fft.fftshift(torch.fft.ifft2(grid) * size**2)  # sum_m q_m exp(+2 pi i k' m / size)
            if len(self._tables) > 4:
                self._tables.clear()
            self._tables[key] = (torch.stack([dense.real, dense.imag])[None], size)
        return self._tables[key]

    def inside(self, nu_t: torch.Tensor, nu_s: torch.Tensor) -> torch.Tensor:
        """The table's frequency range (|k| < N): the OTF is 0 beyond (past the diffraction cutoff)."""
        return ((nu_t / self.cut_t * self.n).abs() < self.n) & ((nu_s / self.cut_s * self.n).abs() < self.n)

    def __call__(self, nu_t: torch.Tensor, nu_s: torch.Tensor, radius_mm: float = math.inf) -> torch.Tensor:
        img, size = self.table(radius_mm)
        half = size / 2  # the dense table's DC index; size / 2N dense steps per table shift k = nu / cut x N
        kt = self.sign_t * nu_t / self.cut_t * half
        ks = self.sign_s * nu_s / self.cut_s * half
        gy = (kt + half) / (2 * half - 1) * 2 - 1
        gx = (ks + half) / (2 * half - 1) * 2 - 1
        g = torch.stack([gx, gy], -1).reshape(1, 1, -1, 2).to(torch.float64)
        v = F.grid_sample(img, g, mode="bilinear", padding_mode="zeros", align_corners=True)[0, :, 0]
        out = torch.complex(v[0], v[1]).reshape(nu_t.shape)
        return torch.where(self.inside(nu_t, nu_s), out, torch.zeros_like(out))


def otf_sampler(analysis: LensAnalysis, field: float, wavelength_nm: float, samples: int = 64,
                max_samples: int = 256) -> TableOTF:
    """The OTF of one (field, wavelength) as a function ``(nu_t, nu_s) -> complex OTF`` (:class:`TableOTF`)."""
    return TableOTF(analysis, field, wavelength_nm, samples, max_samples)


def psf_on_grid(sampler, azimuths_rad: torch.Tensor, dx_mm: float, size: int) -> torch.Tensor:
    """PSFs ``[A, size, size]`` (sum 1, centre at ``size // 2``) rotated to each azimuth (angle of the field
    direction from +y towards +x), sampled with pitch ``dx_mm``; rows are y, columns x.

    The OTF is rotated in the frequency domain (``nu_t = fx ux + fy uy``, ``nu_s = fx vx + fy vy``): exact for a
    :class:`TableOTF`, whose PSF is cut to the disc the kernel's window holds (its light beyond is left out rather
    than wrapped to the window's opposite edge; the same disc at every azimuth).
    """
    f = torch.fft.fftfreq(size, d=dx_mm, dtype=torch.float64)
    fy, fx = torch.meshgrid(f, f, indexing="ij")
    radius = (size // 2 + 0.5) * dx_mm
    out = []
    for phi in azimuths_rad.tolist():
        ux, uy = math.sin(phi), math.cos(phi)  # radial (tangential) direction
        vx, vy = math.cos(phi), -math.sin(phi)  # perpendicular (sagittal) direction
        nu_t, nu_s = fx * ux + fy * uy, fx * vx + fy * vy
        otf = sampler(nu_t, nu_s, radius) if isinstance(sampler, TableOTF) else sampler(nu_t, nu_s)
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
