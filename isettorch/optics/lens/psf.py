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

from .analysis import LensAnalysis, pupil_grid

__all__ = ["TableOTF", "otf_sampler", "psf_on_grid", "geometric_psf", "chief_ray_heights_mm", "spot_radius_mm",
           "ALIASED_STEP_WAVES", "NARROW_PSF_SAMPLES"]

#: A wavefront changing by more than this many waves between neighbouring pupil samples (at the largest pupil grid
#: allowed) tilts the outermost rays past half the FFT PSF's period (a linear phase of s waves per sample shifts the
#: PSF by s periods): the PSF wraps into its period. LensOptics then takes the geometric spot instead.
ALIASED_STEP_WAVES = 0.5


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
        #: the wavefront's largest change between neighbouring pupil samples (waves): above 1/2 the PSF is wider than
        #: the table's period and wraps into it (:data:`ALIASED_STEP_WAVES`)
        self.max_step_waves = float(pf["max_step_waves"])
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
            if len(self._tables) > 6:
                self._tables.clear()
            self._tables[key] = (torch.stack([dense.real, dense.imag])[None], size)
        return self._tables[key]

    def masses(self, dx_mm: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The one-period PSF as point masses ``(t, s, w)`` in the image plane (mm along the field direction and
        across it from the chief ray; ``w`` >= 0), its samples summed in blocks up to ``dx_mm / 8`` wide at their
        weighted centres (so the first moments stay exact); cached per block size."""
        two_n = 2 * self.n
        step = 1 / (2 * max(self.cut_t, self.cut_s))
        b = 1
        while two_n % (2 * b) == 0 and 2 * b * step <= dx_mm / 8:
            b *= 2
        if ("masses", b) not in self._tables:
            w = torch.fft.fftshift(self.q.real).clamp_min(0)
            # otf(nu) = sum_m q_m exp(+2 pi i nu T_m) (see __init__), against the standard exp(-2 pi i nu x): the
            # light of q_m lies at x = -T_m
            t, s = -torch.fft.fftshift(self.t_mm), -torch.fft.fftshift(self.s_mm)
            blocks = (two_n // b, b, two_n // b, b)
            wb = w.reshape(blocks).sum((1, 3))
            safe = torch.where(wb > 0, wb, torch.ones_like(wb))
            keep = wb > 0
            self._tables[("masses", b)] = ((w * t).reshape(blocks).sum((1, 3))[keep] / safe[keep],
                                           (w * s).reshape(blocks).sum((1, 3))[keep] / safe[keep], wb[keep])
        return self._tables[("masses", b)]

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
    radius = (size // 2 + 0.5) * dx_mm
    if isinstance(sampler, TableOTF):
        t, s, w = sampler.masses(dx_mm)
        if _narrow(t, s, w, dx_mm):
            return _splat(t, s, w, azimuths_rad, dx_mm, size, band_limited=False)
    f = torch.fft.fftfreq(size, d=dx_mm, dtype=torch.float64)
    fy, fx = torch.meshgrid(f, f, indexing="ij")
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


def geometric_psf(analysis: LensAnalysis, field: float, wavelength_nm: float, azimuths_rad: torch.Tensor,
                  dx_mm: float, size: int, samples: int = 256) -> torch.Tensor:
    """Geometric PSFs ``[A, size, size]`` (sum 1, the chief ray at ``size // 2``, rows y, columns x, rotated to each
    azimuth as :func:`psf_on_grid`): the unvignetted rays of a ``samples`` x ``samples`` grid over the entrance pupil
    (equal areas, so equal flux) land on the sensor plane at offsets (t, s) from the chief ray (along the field
    direction and across it), and each is shared bilinearly among the four nearest samples of the kernel grid; rays
    beyond the kernel window's disc are left out, as in :func:`psf_on_grid`.

    The PSF of geometrical optics, which the diffraction PSF approaches where the wavefront's aberration spans many
    waves (stationary phase; Born & Wolf, *Principles of Optics*, 7th ed., section 8.1 / 9.1), and the one a pupil
    FFT cannot give when the wavefront is too steep for its grid (:data:`ALIASED_STEP_WAVES`)."""
    t, s = _ray_offsets_mm(analysis, field, wavelength_nm, samples)
    if not t.numel():
        raise ValueError(f"field {field} at {wavelength_nm} nm: every ray of the pupil is vignetted")
    w = torch.ones_like(t)
    return _splat(t, s, w, azimuths_rad, dx_mm, size, band_limited=not _narrow(t, s, w, dx_mm))


#: a PSF whose 80 % encircled-energy radius (about its centroid) is under this many samples is made into a kernel by
#: sharing its light bilinearly among the samples (:func:`_splat`), not band-limited: the band-limited samples of a
#: PSF narrower than a sample ring (the sinc of a sub-sample offset), and clamping the negative lobes left positive
#: ones on alternate samples up to the window's edge, which a uniform scene summed into 8 % too much light at the
#: centre of a singlet's image at 0.31 mm pitch (a Gaussian of sigma 0.84 samples has this radius; its transform is
#: 3 % at the Nyquist frequency)
NARROW_PSF_SAMPLES = 1.5


def _narrow(t: torch.Tensor, s: torch.Tensor, w: torch.Tensor, dx_mm: float) -> bool:
    """Whether the point masses' 80 % encircled-energy radius about their centroid is under
    :data:`NARROW_PSF_SAMPLES` samples of ``dx_mm``."""
    total = w.sum()
    ct, cs = (w * t).sum() / total, (w * s).sum() / total
    r2 = (t - ct) ** 2 + (s - cs) ** 2
    return float(w[r2 < (NARROW_PSF_SAMPLES * dx_mm) ** 2].sum()) > 0.8 * float(total)


#: the gridding's oversampling: the point masses are shared bilinearly on a grid of dx / 4, whose transform's
#: aliases then weigh at most sinc^2(7/8) / sinc^2(1/8) = 0.3 % of the kernel's band (Jackson et al., IEEE TMI
#: 10(3), 1991, gridding with a triangle kernel)
_SPLAT_OVERSAMPLING = 4


def _splat(t: torch.Tensor, s: torch.Tensor, w: torch.Tensor, azimuths_rad: torch.Tensor, dx_mm: float,
           size: int, band_limited: bool = True) -> torch.Tensor:
    """Kernels ``[A, size, size]`` (sum 1, centre ``size // 2``) from point masses ``w`` at offsets ``(t, s)`` (mm,
    along the field direction and across it), rotated to each azimuth as :func:`psf_on_grid`. ``band_limited``: the
    band-limited samples the Fourier path gives, by gridding (the masses shared bilinearly on a grid 4 times finer
    over the same period ``size dx``, transformed, divided by the triangle's transform sinc^2 per axis, cut to the
    kernel's band and transformed back, negative lobes clamped); else each mass shared bilinearly among its four
    nearest samples (positive, no ringing: for PSFs narrower than a sample, :data:`NARROW_PSF_SAMPLES`). Masses beyond
    the window's disc (radius ``(size // 2 + 0.5) dx``) are left out, as the Fourier path leaves the PSF's light
    beyond it out."""
    m = size // 2
    radius = (m + 0.5) * dx_mm
    keep = t * t + s * s <= radius * radius
    t, s, w = t[keep], s[keep], w[keep]
    if not bool((w > 0).any()):
        raise ValueError("the PSF has no light within the kernel window")
    os_ = _SPLAT_OVERSAMPLING if band_limited else 1
    fine = os_ * size
    h = dx_mm / os_
    k = torch.fft.fftfreq(size, d=1.0 / size, dtype=torch.float64).long()  # -m..m in FFT order
    apod = torch.sinc(k.to(torch.float64) / fine) ** 2
    deapod = 1.0 / (apod[:, None] * apod[None, :])
    out = []
    for phi in azimuths_rad.tolist():
        ux, uy = math.sin(phi), math.cos(phi)  # field direction at this azimuth
        vx, vy = math.cos(phi), -math.sin(phi)
        col = (t * ux + s * vx) / h + (0 if band_limited else m)
        row = (t * uy + s * vy) / h + (0 if band_limited else m)
        r0, c0 = torch.floor(row), torch.floor(col)
        wr, wc = row - r0, col - c0
        grid = torch.zeros(fine * fine, dtype=torch.float64)
        for dr, dc, wk in ((0, 0, (1 - wr) * (1 - wc)), (0, 1, (1 - wr) * wc), (1, 0, wr * (1 - wc)),
                           (1, 1, wr * wc)):
            rr, cc = r0.long() + dr, c0.long() + dc
            if band_limited:  # periodic: index 0 is the centre
                grid.index_add_(0, (rr % fine) * fine + cc % fine, w * wk)
            else:  # index m is the centre; the disc lies within the window
                ok = (rr >= 0) & (rr < size) & (cc >= 0) & (cc < size)
                grid.index_add_(0, (rr * size + cc)[ok], (w * wk)[ok])
        if band_limited:
            spec = torch.fft.fft2(grid.reshape(fine, fine))[k % fine][:, k % fine] * deapod
            psf = torch.fft.fftshift(torch.fft.ifft2(spec).real).clamp_min(0)
        else:
            psf = grid.reshape(size, size)
        out.append(psf / psf.sum())
    return torch.stack(out)


def chief_ray_heights_mm(analysis: LensAnalysis, fields: torch.Tensor, wavelength_nm: float) -> torch.Tensor:
    """Chief-ray image heights (mm) on the sensor plane (:attr:`LensAnalysis.sensor_z`: the primary wavelength's
    paraxial focus, or the prescription's own image plane) for field fractions ``fields``."""
    z = analysis.sensor_z
    out = []
    for f in fields.tolist():
        out.append(analysis.chief_ray(f, wavelength_nm, image_z=z)[0][1])
    return torch.stack(out)


def _ray_offsets_mm(analysis: LensAnalysis, field: float, wavelength_nm: float, samples: int
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Where the unvignetted rays of a ``samples`` x ``samples`` grid over the entrance pupil land on the sensor
    plane, from the chief ray (mm): ``(t, s)`` along the field direction (+y: :meth:`LensAnalysis.rays`) and
    across it."""
    theta = analysis.field_angle_deg(field)
    px, py, m = pupil_grid(samples)
    z = analysis.sensor_z
    with torch.no_grad():
        b = analysis.rays(theta, px[m], py[m], wavelength_nm)
        pts, _ = analysis.to_plane(b, z)
        c, _ = analysis.chief_ray(field, wavelength_nm, image_z=z)
    ok = b.valid
    return (pts[ok, 1] - c[1]).to(torch.float64), (pts[ok, 0] - c[0]).to(torch.float64)


def spot_radius_mm(analysis: LensAnalysis, field: float, wavelength_nm: float, samples: int = 24) -> float:
    """Largest distance of a traced (unvignetted) ray from the chief ray on the sensor plane (mm)."""
    t, s = _ray_offsets_mm(analysis, field, wavelength_nm, samples)
    return float(torch.sqrt(t * t + s * s).max()) if t.numel() else 0.0
