"""Fast, physically based synthetic training scenes for demosaicing and colour (training helper).

A scene is a dead-leaves layout (Lee, Mumford, Huang, IJCV 2001: occluding shapes with a scale-invariant size
distribution) of materials with spectral reflectances, lit by one illuminant and seen by a camera with spectral
channel sensitivities. Because the sensor integral is linear in reflectance, every material's camera RGB is
computed once from its spectrum (``rgb = sum_l R(l) E(l) S_c(l) dl``, photon units) and the layout is painted in
camera RGB: edges (anti-aliased by their signed distance), gratings, shading and two-material textures are linear
mixtures of materials, so the image equals the spectral render integrated pixel by pixel.

Reflectances: smooth sigmoid-polynomial spectra (Jakob & Hanika, "A low-dimensional function space for efficient
spectral upsampling", EG 2019) and the ColorChecker spectra shipped with colour-science, plus greys.
Illuminants: CIE daylight 4000-20000 K, Planck 2500-8000 K, A and the F series (isettorch.spectral.illuminant).
Sensitivities: Nikon D5100 and Sigma SD Merrill (colour-science, NPL data), random Gaussian triplets, and the
sRGB colour matching functions (XYZ CMFs x the IEC 61966-2-1 matrix: a camera whose white-balanced RGB is linear
sRGB, which gives saturated, McMaster-like colours).

Every draw comes from an explicit ``torch.Generator``; a batch depends only on (seed, index).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from isettorch import spectral
from isettorch.image import XYZ_TO_LINEAR_SRGB

WAVELENGTHS = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)


def _colour_checker_reflectances() -> torch.Tensor:
    import colour

    out = []
    for key in ("BabelColor Average", "ColorChecker N Ohta"):
        for sd in colour.characterisation.SDS_COLOURCHECKERS[key].values():
            out.append(spectral.resample(torch.tensor(sd.values, dtype=torch.float64),
                                         torch.tensor(sd.wavelengths, dtype=torch.float64), WAVELENGTHS))
    return torch.stack(out)


def _camera_sensitivities() -> list[torch.Tensor]:
    import colour

    out = []
    for key in ("Nikon 5100 (NPL)", "Sigma SDMerill (NPL)"):
        m = colour.characterisation.MSDS_CAMERA_SENSITIVITIES[key]
        s = spectral.resample(torch.tensor(m.values, dtype=torch.float64).T,
                              torch.tensor(m.wavelengths, dtype=torch.float64), WAVELENGTHS)
        out.append(s / s.max())
    xyz = spectral.cmfs(WAVELENGTHS, dtype=torch.float64)
    out.append(torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ xyz)
    return out


def _illuminant_bank() -> torch.Tensor:
    names = ["A", "D65", "D50", "D75"] + [f"F{i}" for i in range(1, 13)]
    names += [f"D{t}" for t in range(4000, 20001, 1000)] + [f"blackbody{t}" for t in range(2500, 8001, 500)]
    spds = []
    for n in names:
        e = spectral.illuminant(n, WAVELENGTHS, dtype=torch.float64)
        p = spectral.energy_to_photons(e, WAVELENGTHS, dim=0)
        spds.append(p / p.max())
    return torch.stack(spds)


class SceneSampler:
    """Draws batches of synthetic linear camera-RGB images (white-balanced, white = 1).

    Args:
        size: image height = width in pixels (even).
        n_shapes: occluding shapes per image.
        sensitivities: ``"all"``, ``"cameras"`` (measured cameras + Gaussian), or ``"srgb"`` only.

    ``sample(batch, generator)`` returns ``[B, 3, size, size]`` float32.
    """

    def __init__(self, size: int = 96, n_shapes: int = 60, sensitivities: str = "all", pool: int = 12):
        if size < 8 or size % 2:
            raise ValueError(f"size: expected an even size >= 8, got {size}")
        if sensitivities not in ("all", "cameras", "srgb"):
            raise ValueError(f"sensitivities: expected 'all', 'cameras' or 'srgb', got {sensitivities!r}")
        self.size, self.n_shapes, self.pool = int(size), int(n_shapes), int(pool)
        self.sens_mode = sensitivities
        self.checker = _colour_checker_reflectances()
        cams = _camera_sensitivities()
        self.measured = cams[:2]
        self.srgb_cmf = cams[2]
        self.illuminants = _illuminant_bank()
        self.dl = spectral.wavelength_weights(WAVELENGTHS)
        t = (WAVELENGTHS - 550.0) / 150.0
        self.t_powers = torch.stack([torch.ones_like(t), t, t * t])  # [3, L]

    # --- spectra --------------------------------------------------------------------------------
    def reflectances(self, n: int, g: torch.Generator) -> torch.Tensor:
        """[n, L] reflectances in [0, 1]: sigmoid polynomials, ColorChecker patches (scaled) and greys."""
        kind = torch.rand(n, generator=g, dtype=torch.float64)
        coef = torch.randn(n, 3, generator=g, dtype=torch.float64) * torch.tensor([2.0, 5.0, 8.0],
                                                                                  dtype=torch.float64)
        sig = torch.sigmoid(coef @ self.t_powers)
        sig = sig * (0.05 + 0.95 * torch.rand(n, 1, generator=g, dtype=torch.float64))
        idx = torch.randint(0, self.checker.shape[0], (n,), generator=g)
        chk = self.checker[idx] * (0.3 + 0.9 * torch.rand(n, 1, generator=g, dtype=torch.float64))
        grey = torch.rand(n, 1, generator=g, dtype=torch.float64).expand(-1, WAVELENGTHS.numel())
        out = torch.where(kind[:, None] < 0.6, sig, torch.where(kind[:, None] < 0.85, chk, grey))
        return out.clamp(0.0, 1.0)

    def sensitivity(self, g: torch.Generator) -> torch.Tensor:
        """[3, L] channel sensitivities for one image."""
        u = float(torch.rand(1, generator=g))
        if self.sens_mode == "srgb" or (self.sens_mode == "all" and u < 0.35):
            return self.srgb_cmf
        if (self.sens_mode == "all" and u < 0.7) or (self.sens_mode == "cameras" and u < 0.5):
            return self.measured[int(torch.randint(0, 2, (1,), generator=g))]
        peaks = torch.tensor([455.0, 540.0, 605.0], dtype=torch.float64) + 15 * torch.randn(3, generator=g,
                                                                                         dtype=torch.float64)
        widths = 25.0 + 25.0 * torch.rand(3, generator=g, dtype=torch.float64)
        return torch.exp(-0.5 * ((WAVELENGTHS[None] - peaks[:, None]) / widths[:, None]) ** 2)

    def material_rgb(self, batch: int, g: torch.Generator) -> torch.Tensor:
        """[B, P, 3] white-balanced camera RGB of a pool of P materials per image."""
        out = []
        for _ in range(batch):
            refl = self.reflectances(self.pool, g)
            ill = self.illuminants[int(torch.randint(0, self.illuminants.shape[0], (1,), generator=g))]
            sens = self.sensitivity(g)
            m = (ill * self.dl)[:, None] * sens.T  # [L, 3]; camera response to photons
            white = m.sum(0)  # perfect white reflector
            out.append((refl @ m) / white)  # von Kries white balance: white -> (1, 1, 1)
        return torch.stack(out).float()

    # --- layout ---------------------------------------------------------------------------------
    def sample(self, batch: int, g: torch.Generator) -> torch.Tensor:
        s, n = self.size, self.n_shapes
        mats = self.material_rgb(batch, g)  # [B, P, 3]
        P = mats.shape[1]
        yy, xx = torch.meshgrid(torch.arange(s, dtype=torch.float32), torch.arange(s, dtype=torch.float32),
                                indexing="ij")
        yy, xx = yy[None], xx[None]  # [1, S, S]

        def rnd(*shape):
            return torch.rand(*shape, generator=g)

        def pick():
            idx = torch.randint(0, P, (batch,), generator=g)
            return mats[torch.arange(batch), idx][:, :, None, None]  # [B, 3, 1, 1]

        img = pick().expand(-1, -1, s, s).clone()
        # radii log-uniform between r_min and r_max (equal count per octave), painted large to small so every
        # scale stays visible (a dead-leaves layout truncated to n shapes)
        r_min, r_max = 2.0, s * 0.7
        radii = r_min * (r_max / r_min) ** torch.rand(batch, n, generator=g)
        radii = radii.sort(dim=1, descending=True).values
        for i in range(n):
            cy, cx = (rnd(batch) * 1.2 - 0.1) * s, (rnd(batch) * 1.2 - 0.1) * s
            r = radii[:, i]
            theta = rnd(batch) * math.pi
            ct, st = torch.cos(theta)[:, None, None], torch.sin(theta)[:, None, None]
            dy, dx = yy - cy[:, None, None], xx - cx[:, None, None]
            u_ = dx * ct + dy * st
            v_ = -dx * st + dy * ct
            rr = r[:, None, None]
            kind = rnd(batch)[:, None, None]
            aspect = (0.2 + 0.8 * rnd(batch))[:, None, None]
            line_w = (0.4 + 2.5 * rnd(batch) ** 2)[:, None, None]
            d_disc = torch.sqrt(u_ ** 2 + (v_ / aspect) ** 2) - rr  # ellipse (approximate distance)
            d_rect = torch.maximum(u_.abs() - rr, v_.abs() - rr * aspect)
            d_line = torch.maximum(v_.abs() - line_w / 2, u_.abs() - 3 * rr)
            d_half = torch.maximum(v_, (u_ ** 2 + v_ ** 2).sqrt() - 2.5 * rr)
            d = torch.where(kind < 0.35, d_disc, torch.where(kind < 0.7, d_rect,
                                                             torch.where(kind < 0.85, d_line, d_half)))
            blur = (0.3 + 1.7 * rnd(batch) ** 2)[:, None, None]
            alpha = (0.5 - d / (2 * blur)).clamp(0, 1)[:, None]  # anti-aliased coverage
            # texture: flat, grating (up to near Nyquist), shading, or blotchy two-material mix
            # natural scenes: few materials, most edges are changes of intensity (shading, illumination) at a
            # constant chromaticity, which is the inter-channel correlation demosaicing relies on
            bright = (0.15 + 0.85 * rnd(batch))[:, None, None, None]
            c1 = pick() * bright
            c2 = torch.where(rnd(batch)[:, None, None, None] < 0.5, c1 * (0.2 + 0.6 * rnd(batch))[:, None, None, None],
                             pick() * bright)
            tk = rnd(batch)[:, None, None, None]
            freq = (0.02 + 0.46 * rnd(batch) ** 2.5)[:, None, None]
            phi = torch.atan2(torch.randn(batch, generator=g), torch.randn(batch, generator=g))
            grating = 0.5 + 0.5 * torch.sin(2 * math.pi * freq * u_ + phi[:, None, None])
            grating = torch.where(rnd(batch)[:, None, None] < 0.3, (grating > 0.5).float(), grating)[:, None]
            shade = (1 + (0.8 * rnd(batch) - 0.4)[:, None, None] * v_ / rr.clamp_min(1))[:, None].clamp(0.2, 2)
            low = torch.rand(batch, 1, 6, 6, generator=g)
            blot = F.interpolate(low, size=(s, s), mode="bicubic", align_corners=False).clamp(0, 1)
            colour = torch.where(tk < 0.55, c1, torch.where(
                tk < 0.7, c1 * grating + c2 * (1 - grating),
                torch.where(tk < 0.85, c1 * shade, c1 * blot + c2 * (1 - blot))))
            img = img * (1 - alpha) + colour * alpha
        return (img * self.pink_texture(batch, g)).clamp_min(0)

    def pink_texture(self, batch: int, g: torch.Generator) -> torch.Tensor:
        """[B, 3, S, S] multiplicative 1/f^beta texture (natural-image power spectrum, Field 1987), mostly achromatic:
        the fine, low-contrast stochastic detail of natural surfaces that flat shapes lack."""
        s = self.size
        fy = torch.fft.fftfreq(s)[:, None]
        fx = torch.fft.rfftfreq(s)[None, :]
        f = torch.sqrt(fx ** 2 + fy ** 2).clamp_min(1.0 / s)
        beta = (0.8 + 0.8 * torch.rand(batch, generator=g))[:, None, None, None]
        white = torch.randn(batch, 2, s, s, generator=g)
        tex = torch.fft.irfft2(torch.fft.rfft2(white) / f ** beta, s=(s, s))
        tex = tex / tex.flatten(2).std(-1)[..., None, None].clamp_min(1e-8)
        amp = (0.12 * torch.rand(batch, generator=g) ** 1.5)[:, None, None, None]
        lum, chroma = tex[:, :1], tex[:, 1:2] * torch.tensor([1.0, 0.0, -1.0]).reshape(1, 3, 1, 1)
        return (1 + amp * (lum + 0.15 * chroma)).clamp_min(0.05)


def encode(img: torch.Tensor, g: torch.Generator, p_gamma: float = 0.7, exposure=(0.6, 1.3)) -> torch.Tensor:
    """Random exposure then, with probability ``p_gamma``, a power-law encoding (gamma 1.8-2.6); clipped to [0, 1].

    The benchmarks' ground truth is 8-bit sRGB-encoded data scored as if linear, so training sees both.
    """
    b = img.shape[0]
    peak = img.flatten(1).quantile(0.98, dim=1).clamp_min(1e-3)
    k = (exposure[0] + (exposure[1] - exposure[0]) * torch.rand(b, generator=g)) / peak
    x = (img * k[:, None, None, None]).clamp(0, 1)
    gam = 1.8 + 0.8 * torch.rand(b, generator=g)
    use = (torch.rand(b, generator=g) < p_gamma)[:, None, None, None]
    return torch.where(use, x.clamp_min(1e-8) ** (1 / gam[:, None, None, None]), x)


def mosaic_rggb(rgb: torch.Tensor) -> torch.Tensor:
    """[B, 3, H, W] -> RGGB mosaic [B, 1, H, W]."""
    raw = rgb[:, 1:2].clone()
    raw[:, 0, 0::2, 0::2] = rgb[:, 0, 0::2, 0::2]
    raw[:, 0, 1::2, 1::2] = rgb[:, 2, 1::2, 1::2]
    return raw


def augment_flips(img: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    if float(torch.rand(1, generator=g)) < 0.5:
        img = img.flip(-1)
    if float(torch.rand(1, generator=g)) < 0.5:
        img = img.transpose(-1, -2)
    return img


def numpy_seed(seed: int) -> np.random.Generator:  # for callers that need numpy draws
    return np.random.default_rng(seed)


class IsetScenePool:
    """Crops of isettorch.data synthetic scenes (``generate_scene``), rendered to white-balanced camera RGB.

    Generating a spectral scene costs far more than a training step on CPU, so a pool of ``pool`` scenes is kept
    and ``refresh`` new ones replace the oldest at every step: at step ``s`` the pool holds scene indices
    ``[s * refresh, s * refresh + pool)``, so the pool (and every batch) depends only on (seed, step) and a run
    resumes exactly. The camera sensitivities of each scene are drawn from ``sampler`` (same cameras as
    :class:`SceneSampler`); white balance uses the scene's illuminant (``Scene.illuminant_photons``).
    """

    def __init__(self, sampler: SceneSampler, seed: int = 0, scene_size: int = 128, pool: int = 32,
                 refresh: int = 1, config: dict | None = None):
        if scene_size < sampler.size:
            raise ValueError(f"scene_size: expected at least the patch size {sampler.size}, got {scene_size}")
        self.sampler, self.seed, self.scene_size = sampler, int(seed), int(scene_size)
        self.pool_size, self.refresh = int(pool), int(refresh)
        self.config = dict(config or {}, height=self.scene_size, width=self.scene_size)
        self.scenes: dict[int, torch.Tensor] = {}

    def render(self, index: int) -> torch.Tensor:
        from isettorch.data import generate_scene

        s = generate_scene(index, seed=self.seed, config=self.config, dtype=torch.float32)
        w = s.wavelengths_nm.to(torch.float64)
        g = torch.Generator().manual_seed(self.seed * 7_919 + index)
        sens = spectral.resample(self.sampler.sensitivity(g), WAVELENGTHS, w)  # [3, L]
        m = (sens * spectral.wavelength_weights(w)).float()  # photon counting: sum_l S(l) N(l) dl
        rgb = torch.einsum("cl,lhw->chw", m, s.photons[0])
        white = m @ s.illuminant_photons[0]  # the main light's perfect white (von Kries)
        return (rgb / white[:, None, None]).clamp_min(0)

    def advance(self, step: int) -> None:
        lo = step * self.refresh
        keep = range(lo, lo + self.pool_size)
        for k in [k for k in self.scenes if k not in keep]:
            del self.scenes[k]
        for k in keep:
            if k not in self.scenes:
                self.scenes[k] = self.render(k)

    def sample(self, batch: int, step: int, g: torch.Generator) -> torch.Tensor:
        """[B, 3, size, size] random crops (even offsets keep the Bayer phase) from the pool at ``step``."""
        self.advance(step)
        keys = sorted(self.scenes)
        p, n = self.sampler.size, self.scene_size
        out = []
        for _ in range(batch):
            img = self.scenes[keys[int(torch.randint(0, len(keys), (1,), generator=g))]]
            y, x = (2 * int(torch.randint(0, (n - p) // 2 + 1, (1,), generator=g)) for _ in range(2))
            out.append(img[:, y:y + p, x:x + p])
        return torch.stack(out)
