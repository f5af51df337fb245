"""Natural-statistics synthetic scenes for training demosaic and denoise networks (one generator, in the library).

A scene is *factored*: ``J`` abundance maps ``[J, H, W]`` times ``J`` spectra ``[J, L]`` (radiance, photons per unit
map), ``L(x, l) = sum_j map_j(x) spectrum_j(l)``. Materials are palette reflectances under the scene's light;
the maps say how much of each material a pixel sees (coverage x shading). :func:`to_scene` gives the factored
:class:`~isettorch.scene.Scene` (``Scene.from_factors``): every spectral integral is the library's (``Scene.project``,
the :class:`~isettorch.camera.Camera`, which projects each spectrum once), and
:class:`~isettorch.data.camera_pairs.CameraPairDataset` renders these scenes as camera pairs
(``scene.generator: natural``).

Components (each a key of ``NATURAL_DEFAULTS["components"]``; ``enabled: false`` switches it off, the ablation
script ``benchmarks/generator_ablation.py`` does that one at a time), named after their source:

* ``palette``: materials from the measured reflectances shipped by colour-science (each scaled by U(0.3, 1.2) and
  limited to 1, a physical reflectance: about 0.3 % of draws reach 1 at some wavelength, a colour shift of up to
  dE2000 3 from the scaled spectrum), natural chromaticities
  upsampled with ``colour.recovery`` (Mallett & Yuksel, EGSR 2019), and smooth random spectra (PCA of the measured
  set / sigmoid polynomials, Jakob & Hanika, EG 2019); ``materials`` per scene, few, as in natural scenes. With
  ``dye.probability`` (0 in version 5, so its scenes are unchanged) a non-grey material is made purer by a
  log-uniform ``dye.concentration`` (Beer-Lambert, :func:`.spectra.dye_concentration`): the dyed and painted
  surfaces of man-made scenes are more saturated than the measured charts and natural chromaticities.
* ``illuminant``: daylight, blackbody, LED, fluorescent (:func:`.spectra.random_illuminant`), and with
  ``mixed_probability`` a second light blended over the image by a smooth field (mixed illumination).
* ``dead_leaves``: occluding leaves with the scale-invariant radius density ``p(r) ~ r^-3`` (Lee, Mumford & Huang,
  IJCV 2001; Achddou, Gousseau & Ladjal, "Synthetic images as a regularity prior for image restoration neural
  networks", SSVM 2021, and their 2023 follow-up), disks / ellipses / rectangles, anti-aliased by their signed
  distance. Unlike the dead-leaves model proper (:func:`isettorch.scene.dead_leaves`, drawn until the image is
  covered), a fixed number of leaves (``leaves``) is painted, largest first, over a background material: at the
  defaults about 40 % of a scene is leaves (measured 0.39-0.40; a Boolean model gives 0.41), the rest background;
  the image spectrum's slope stays about -1.94. Leaf centres are drawn up to 10 % beyond the image while radii reach
  half its size, so large leaves cover the corners about a quarter less often than the centre (kept: the version-5
  scenes every shipped model was trained on).
* ``textured_leaves``: a leaf's interior is flat, or textured with 1/f^s noise
  (:func:`isettorch.scene.textures.power_law_noise`), a warped grating, or a colour-line blend of two materials
  (Omer & Werman, CVPR 2004) (Achddou et al. 2023).
* ``colour_correlation``: fine detail mostly achromatic: a shared multiplicative shading field (1/f^s, log-normal)
  modulates every material equally, so intensity changes at fine scales and colour at coarse ones (natural-image
  colour statistics: Ruderman, Cronin & Chiao, JOSA A 15, 1998); a leaf of radius ``r`` takes a new material only
  with probability ``min(1, r / chromatic_radius_px)`` (else the material under its centre, at its own
  intensity), and leaf textures and detail items change material with ``chromatic_detail_probability`` (else
  they modulate intensity), so the high-frequency bands of the colour channels are strongly correlated (Gunturk,
  Altunbasak & Mersereau, IEEE TIP 11(9), 2002; measured in benchmarks/SCENE_STATS.md). Off: the same 1/f^s field
  blends each material towards another one instead, and every leaf and item takes a random material (fine detail
  that changes colour).
* ``depth_layers``: a foreground dead-leaves layer over the background, each defocused by the library's optics
  (:meth:`WavefrontOptics.defocus_maps <isettorch.optics.WavefrontOptics.defocus_maps>` at the layer's defocus in
  diopters: the PSF at 550 nm blurs the layer's maps and its coverage, then the layers are composited front over
  back).
* ``fine_detail``: band-limited detail near and above the sensor's Nyquist frequency: gratings at any angle
  (0.15-0.7 cycles/pixel), thin lines (0.3-2 px) and sharp straight edges, rendered ``supersample`` x finer and
  box-averaged (pixel-area integration), so networks see moire and zipper cases.
* ``grain``: with ``probability``, independent pixel-scale grain in three spectral layers (blue, green, red bands
  that sum to 1), log-normal with a mean of ``amplitude`` (log-uniform) of a white: fine structure that R, G and
  B do *not* share, as in colour film's three emulsion layers (Newson, Delon & Galerne, Computer Graphics Forum
  36(8), 2017) and a photograph's per-channel residual noise, also in the dark channels of saturated colours.
  With ``relative.probability`` (0 in version 5, so its scenes are unchanged) the grain also *multiplies* each
  layer: every material's reflectance ``r`` becomes ``r sum_k d_k m_k(x)`` (``d_k`` the layer bands, ``m_k``
  independent log-normal fields of mean 1 and log-std ``relative.contrast``; its default 0.01-0.08 is the additive
  grain's ``amplitude`` relative to an 18 % grey), as a fluctuation of each emulsion layer's dye density scales the
  light that layer passes (Beer-Lambert). Such detail is in proportion to each channel's *own* signal, so a weak
  channel's fine structure is not a scaled copy of the bright one's: version-5 networks copy the weak channels'
  detail into red scaled ~3x (``docs/training_log.md#dye_2026-11-26``).
* ``specular``: with ``probability`` (0 in version 5, so its scenes are unchanged) the interface reflection of the
  dichromatic reflection model (Shafer 1985): on glossy materials a fine log-normal sheen texture, in proportion to
  the material's body map, reflects the illuminant's own spectrum (neutral interface reflection, Lee, Breneman &
  Schulte 1990): it adds light of the illuminant's colour whatever the material's colour. Shading alone makes a
  channel's fine detail proportional to its level (a colour-ratio world); photographs lie between ratio and
  difference (``benchmarks/SCENE_STATS.md``, the detail-ratio exponent).

Defaults: leaf count, smallest radius and shading exponents were set to bring the mean power-spectrum slope of 128 px
scenes towards the published -1.88 (version 5 measures -2.3: benchmarks/SCENE_STATS.md). The colour-correlation defaults
(version 4: ``chromatic_radius_px``, ``chromatic_detail_probability``, 2-8 materials, leaf brightness 0.1-1) were set on
the generator's own scenes so that the R-G correlation of their high-pass bands in linear sRGB is near the 0.9 or more
that Gunturk et al. (2002) report for natural images (0.90-0.94 on samples of 6-16 scenes in the scene space);
as a diagnostic, directional demosaicking (Menon 2007), which relies on that correlation, gained 0.9 dB over
Malvar-He-Cutler on 32 rendered version-4 scenes against 0.1-0.5 dB on version-3 scenes (2.8 dB on a grey-only
variant). Version 5 made colour change at finer scales (``chromatic_radius_px`` 16 -> 8,
``chromatic_detail_probability`` 0.25 -> 0.5) and added ``grain``: the version-4 network fell below
Malvar-He-Cutler on a synthetic stress set of saturated colours with independent per-channel grain
(``training/make_heldout.py --channel-gains 1 0.15 0.15 --grain-std 0.005``), and version-4 scenes had a steeper
power spectrum (-2.54) than the published -1.88. The version-4 distribution is this one with
``{"colour_correlation": {"chromatic_radius_px": 16.0, "chromatic_detail_probability": 0.25}, "grain":
{"enabled": False}}`` (grain draws last, so the earlier draws are the same). Nothing was set on a photograph
test set.

Every draw comes from one ``torch.Generator`` seeded by ``seed_for(seed, index)``: an item depends only on
``(seed, index, config)``. Hard-patch mining (Gharbi, Chaurasia, Paris & Durand, SIGGRAPH Asia 2016) is
:func:`hard_patch_indices`; a folder of the user's own photos is :class:`isettorch.data.photos.PhotoSceneDataset`.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F

from .._checks import dataset_index, item_index
from ..scene import textures as _tex
from . import spectra as _spectra
from .config import (
    COMPONENTS,
    DEFAULT_COMPONENTS,
    NATURAL_DEFAULTS,
    check_integer,
    check_seed,
    natural_config,
    seed_for,
)
from .layouts import dead_leaves_radii
from .scenes import _white_photons

__all__ = ["NATURAL_DEFAULTS", "COMPONENTS", "DEFAULT_COMPONENTS", "natural_config", "generate_natural", "to_scene",
           "hard_patch_indices", "NaturalSceneDataset", "DOMAINS", "expose_and_encode"]

# ------------------------------------------------------------------------------------------------ draws


def _uniform(g: torch.Generator) -> float:
    """One uniform draw in [0, 1) from ``g``, in float32 whatever torch's default dtype (a float64 draw takes the
    generator's stream differently: with set_default_dtype(float64) every later draw of an item moved)."""
    return float(torch.rand((), generator=g, dtype=torch.float32))


def _u(g, lo, hi):
    return lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))


def _ri(g, lo, hi):
    return int(torch.randint(int(lo), int(hi) + 1, (), generator=g))


def _choice(weights: dict, g) -> str:
    keys = [k for k, v in weights.items() if v > 0]
    if not keys:
        raise ValueError(f"weights: expected at least one positive weight, got {weights}")
    w = [float(weights[k]) for k in keys]
    u = float(torch.rand((), generator=g, dtype=torch.float64)) * sum(w)  # inverse CDF of one uniform draw
    for k, wk in zip(keys, w):
        u -= wk
        if u < 0:
            return k
    return keys[-1]


def _wavelengths(cfg) -> torch.Tensor:
    a, b, s = cfg["wavelengths_nm"]
    return torch.arange(float(a), float(b) + 0.5 * float(s), float(s), dtype=torch.float64)


def _palette(cfg, wl, g) -> tuple[torch.Tensor, list[str], list[float]]:
    p = cfg["components"]["palette"]
    dye = p["dye"]
    n = _ri(g, *p["materials"])
    measured = _spectra.measured_reflectances(wl)
    out, kinds, conc = [], [], []
    for _ in range(n):
        conc.append(1.0)
        if p["enabled"]:
            kind = _choice({"measured": p["measured"], "recovery": p["recovery"], "random": p["random"]}, g)
        else:  # ablation: smooth random spectra only (the previous isettorch.data palette)
            kind = "random"
        if kind == "measured":
            r = measured[int(torch.randint(0, measured.shape[0], (), generator=g))]
            r = (r * _u(g, 0.3, 1.2)).clamp(0, 1)
        elif kind == "recovery":
            r = _spectra.recovery_reflectances(1, wl, g)[0]
        else:
            r = _spectra.random_reflectances(1, wl, g, model="mixed")[0].to(torch.float64)
        if p["enabled"] and _uniform(g) < p["grey_probability"]:
            r, kind = torch.full_like(r, math.exp(_u(g, math.log(0.03), math.log(0.9)))), "grey"
        elif p["enabled"] and dye["probability"] > 0 and _uniform(g) < dye["probability"]:
            conc[-1] = math.exp(_u(g, *map(math.log, dye["concentration"])))
            r = _spectra.dye_concentration(r, conc[-1])
        out.append(r)
        kinds.append(kind)
    return torch.stack(out), kinds, conc


def _illuminants(cfg, wl, g, h, w):
    c = cfg["components"]["illuminant"]
    kinds = c["kinds"] if c["enabled"] else {"daylight": 1.0}
    k1 = _choice(kinds, g)
    e1, cct1, name1 = _spectra.random_illuminant(k1, wl, g, None if c["enabled"] else (6500.0, 6500.0))
    lights = [(_white_photons(e1, wl), None)]
    names = [name1]
    if c["enabled"] and _uniform(g) < c["mixed_probability"]:
        e2, _, name2 = _spectra.random_illuminant(_choice(kinds, g), wl, g)
        m = torch.sigmoid(_tex.power_law_noise(h, w, 2.5, g, dtype=torch.float64) * _u(g, 1.0, 4.0))
        ratio = math.exp(_u(g, math.log(0.3), math.log(3.0)))
        lights = [(lights[0][0], (1 - m).float()), (_white_photons(e2, wl) * ratio, m.float())]
        names.append(name2)
    return lights, names, cct1


def _leaf_coverage(h, w, cy, cx, r, aspect, theta, shape):
    """Anti-aliased coverage ([h, w] float32 on the leaf's bounding box) and the box (y0, y1, x0, x1)."""
    ext = r * max(1.0, aspect) * (1.5 if shape == 2 else 1.0) + 1.5
    y0, y1 = max(0, int(math.floor(cy - ext))), min(h, int(math.ceil(cy + ext)) + 1)
    x0, x1 = max(0, int(math.floor(cx - ext))), min(w, int(math.ceil(cx + ext)) + 1)
    if y0 >= y1 or x0 >= x1:
        return None, None
    # numpy: a leaf is a few dozen pixels, where torch's per-op overhead is most of the cost
    yy = np.arange(y0, y1, dtype=np.float32)[:, None] + np.float32(0.5 - cy)
    xx = np.arange(x0, x1, dtype=np.float32)[None, :] + np.float32(0.5 - cx)
    ct, st = np.float32(math.cos(theta)), np.float32(math.sin(theta))
    u, v = xx * ct + yy * st, yy * ct - xx * st
    if shape == 0:  # disk
        d = np.sqrt(u * u + v * v) - np.float32(r)
    elif shape == 1:  # ellipse (distance approximated by the scaled radius)
        q = np.sqrt((u / np.float32(r)) ** 2 + (v / np.float32(r * aspect)) ** 2)
        d = (q - 1) * np.float32(r * min(1.0, aspect))
    else:  # rectangle
        d = np.maximum(np.abs(u) - np.float32(r), np.abs(v) - np.float32(r * aspect))
    return torch.from_numpy(np.clip(np.float32(0.5) - d, 0, 1)), (y0, y1, x0, x1)


def _second_material(cfg, g, k, n_mat):
    """The material a texture or detail item blends with: any of the scene's with the ``colour_correlation``
    component off; with it on, another one only with ``chromatic_detail_probability`` (fine detail is mostly
    achromatic: the same material, another intensity)."""
    cc = cfg["components"]["colour_correlation"]
    if cc["enabled"] and _u(g, 0.0, 1.0) >= cc["chromatic_detail_probability"]:
        return k
    return _ri(g, 0, n_mat - 1)


def _leaf_texture(cfg, g, hh, ww, k, n_mat):
    """(index_b, t [hh, ww] or None, shade [hh, ww] or None): the leaf's second material and blend, and its
    own shading; a flat leaf returns (k, None, None). Leaves whose box is under ``min_size_px`` are flat (a
    texture on a few pixels is not one)."""
    c = cfg["components"]["textured_leaves"]
    if not c["enabled"] or min(hh, ww) < max(2, int(c["min_size_px"])) \
            or _uniform(g) >= c["probability"]:
        return k, None, None
    kind = _choice(c["kinds"], g)
    s = _u(g, *c["noise_exponent"])
    if kind == "noise":  # achromatic texture: the leaf's own log-normal shading
        return k, None, torch.exp(_tex.power_law_noise(hh, ww, s, g) * _u(g, 0.1, 0.5))
    k2 = _second_material(cfg, g, k, n_mat)
    if kind == "grating":
        f = math.exp(_u(g, math.log(c["grating_cpp"][0]), math.log(c["grating_cpp"][1])))
        t = _tex.warped_grating(hh, ww, f, _u(g, 0, math.pi), _u(g, 0.0, 3.0), g)
    else:
        t = _tex.colour_line_weights(hh, ww, s, g, contrast=_u(g, 0.5, 2.0))
    if k2 == k:  # same material: an intensity texture
        return k, None, 0.4 + 0.8 * t
    return k2, t, None


def _paint_leaves(cfg, g, maps, n_leaves, r_min, r_max, exponent, alpha=None):
    """Paint ``n_leaves`` dead leaves back to front onto ``maps`` [K, H, W] in place (and onto ``alpha`` [H, W]
    when given: the layer's coverage). Radii: ``p(r) ~ r^-exponent`` (inverse CDF; exponent 3 is
    :func:`.layouts.dead_leaves_radii`); painted large to small so every scale stays visible.

    Materials: with the ``colour_correlation`` component on, a leaf of radius ``r`` takes a new random material
    with probability ``min(1, r / chromatic_radius_px)`` and otherwise the material already at its centre (a change
    of intensity only): colour changes at coarse scales, intensity at all scales, as in natural images (the
    high-frequency bands of R, G and B are strongly correlated: Gunturk, Altunbasak & Mersereau, IEEE TIP 11(9)
    2002; benchmarks/SCENE_STATS.md). Off (and on an empty layer): every leaf a random material."""
    cc = cfg["components"]["colour_correlation"]
    r_chroma = float(cc["chromatic_radius_px"]) if cc["enabled"] else 0.0
    b_lo, b_hi = (float(b) for b in cfg["components"]["dead_leaves"]["brightness"])
    n_mat, h, w = maps.shape
    if abs(exponent - 3.0) < 1e-12:
        radii = dead_leaves_radii(n_leaves, r_min, r_max, g)
    else:
        u = torch.rand(n_leaves, generator=g, dtype=torch.float64)
        a = 1.0 - exponent
        radii = (r_min**a + u * (r_max**a - r_min**a)) ** (1 / a)
    radii = radii.sort(descending=True).values
    drawn = radii.tolist()  # the drawn sizes (leaves falling outside the image are drawn, then not painted)
    # every leaf's geometry, material and brightness in one draw per quantity (the texture draws follow per leaf)
    u = torch.rand(n_leaves, 7, generator=g, dtype=torch.float64).tolist()
    k_all = torch.randint(0, n_mat, (n_leaves,), generator=g).tolist()
    for r, (u_y, u_x, u_s, u_a, u_t, u_b, u_m), k in zip(drawn, u, k_all):
        cy, cx = (-0.1 + 1.2 * u_y) * h, (-0.1 + 1.2 * u_x) * w
        if r_chroma > 0 and u_m >= r / r_chroma:  # keep the material under the leaf's centre
            under = maps[:, min(h - 1, max(0, int(cy))), min(w - 1, max(0, int(cx)))]
            if float(under.max()) > 0:
                k = int(under.argmax())
        shape = min(2, int(3 * u_s))
        aspect, theta = 0.3 + 0.7 * u_a, math.pi * u_t
        brightness = b_lo * (b_hi / b_lo) ** u_b  # log-uniform in [b_lo, b_hi]
        cov, box = _leaf_coverage(h, w, cy, cx, r, aspect, theta, shape)
        if cov is None:
            continue
        y0, y1, x0, x1 = box
        k2, t, shade = _leaf_texture(cfg, g, y1 - y0, x1 - x0, k, n_mat)
        region = maps[:, y0:y1, x0:x1]
        region.mul_(1 - cov)
        contrib = cov * brightness * (shade if shade is not None else 1.0)
        if t is None:
            region[k].add_(contrib)
        else:
            region[k].add_(contrib * (1 - t))
            region[k2].add_(contrib * t)
        if alpha is not None:
            a_reg = alpha[y0:y1, x0:x1]
            a_reg.mul_(1 - cov).add_(cov)
    return drawn


@functools.lru_cache(maxsize=32)
def _layer_optics(f_number: float, focal_length_m: float):
    """The lens that images the depth layers, focused where a layer's defocus is 0 (built once per setting by the
    optics config factory, :func:`isettorch.optics.factory.build_optics`, as a camera's ``optics:`` section of type
    ``wavefront``; the optics blur each layer: :meth:`~isettorch.optics.WavefrontOptics.defocus_maps`)."""
    from ..optics.factory import build_optics

    return build_optics({"type": "wavefront", "f_number": f_number, "focal_length_m": focal_length_m})


def _fine_detail(cfg, g, maps):
    """Overlay band-limited items (gratings, thin lines, edges) rendered supersampled and box-averaged."""
    c = cfg["components"]["fine_detail"]
    n_mat, h, w = maps.shape
    ss = int(c["supersample"])
    kinds = []
    for _ in range(_ri(g, *c["items"])):
        kind = ("grating", "line", "edge")[_ri(g, 0, 2)]
        ang = _u(g, 0.0, math.pi)
        k = _second_material(cfg, g, -1, n_mat)  # -1: the same materials as below it (an intensity change)
        yy = (torch.arange(h * ss, dtype=torch.float64)[:, None] + 0.5) / ss
        xx = (torch.arange(w * ss, dtype=torch.float64)[None, :] + 0.5) / ss
        u = xx * math.cos(ang) + yy * math.sin(ang)
        v = -xx * math.sin(ang) + yy * math.cos(ang)
        cy, cx = _u(g, 0.2 * h, 0.8 * h), _u(g, 0.2 * w, 0.8 * w)
        u0 = cx * math.cos(ang) + cy * math.sin(ang)
        v0 = -cx * math.sin(ang) + cy * math.cos(ang)
        if kind == "grating":  # a patch (half-plane-limited) of a square or sine grating
            f = _u(g, *c["grating_cpp"])
            wave = torch.sin(2 * math.pi * f * (u - u0))
            pattern = (wave > 0).double() if _uniform(g) < 0.5 else 0.5 + 0.5 * wave
            half = _u(g, 0.15, 0.5) * min(h, w)
            cover = ((u - u0).abs() < half) & ((v - v0).abs() < half)
            cov = cover.double() * pattern
        elif kind == "line":
            width = _u(g, *c["line_width_px"])
            cov = ((v - v0).abs() < width / 2).double()
        else:
            cov = (v > v0).double()
        cov = F.avg_pool2d(cov[None, None], ss)[0, 0].float()  # pixel-area integration
        brightness = math.exp(_u(g, math.log(0.2), 0.0))
        if k < 0:  # achromatic: the materials below, at another intensity
            maps.mul_(1 - cov + cov * brightness)
        else:
            maps.mul_(1 - cov).add_(F.one_hot(torch.tensor(k), n_mat).float()[:, None, None] * cov * brightness)
        kinds.append(kind)
    return kinds


def grain_dyes(cfg: dict, wl: torch.Tensor) -> torch.Tensor:
    """The ``grain`` component's three layer reflectances ``[3, L]`` (blue, green, red bands split by sigmoid edges at
    ``dye_edges_nm`` of width ``dye_width_nm``); they sum to 1 at every wavelength, so equal grain in the three
    layers is grey."""
    c = cfg["components"]["grain"]
    lo, hi = (float(e) for e in c["dye_edges_nm"])
    width = float(c["dye_width_nm"])
    if not (lo < hi and width > 0):
        raise ValueError(f"grain: expected dye_edges_nm increasing and dye_width_nm > 0, got {[lo, hi]}, {width}")
    w0, w1 = float(wl.min()), float(wl.max())
    if not (w0 < lo and hi < w1):  # (edges at 100 and 900 nm had left one dye at 1 everywhere: achromatic grain)
        raise ValueError(f"config: 'components.grain.dye_edges_nm': expected both edges inside the wavelength grid "
                         f"({w0:g}-{w1:g} nm), so that each of the three dyes has a band; got {[lo, hi]}")
    a, b = torch.sigmoid((wl - lo) / width), torch.sigmoid((wl - hi) / width)
    return torch.stack([1 - a, a - b, b])


def _grain(cfg, g, h, w) -> tuple[torch.Tensor, float]:
    """Grain maps ``[3, H, W]`` (one per layer of :func:`grain_dyes`) and their mean amplitude: independent
    log-normal fields ``a exp(c n - c^2 / 2)`` (mean ``a``), ``n`` unit-std 1/f^s noise with ``s`` near 0 (grain is
    pixel-scale). Colour film's three emulsion layers grain independently (Newson, Delon & Galerne, "A stochastic
    film grain model for resolution-independent rendering", Computer Graphics Forum 36(8), 2017), and a
    photograph's residual noise is independent per channel, so photographs carry fine structure that is *not*
    shared by R, G and B, also in the dark channels of saturated colours; without it a network learns a
    colour-ratio prior that scales the bright channel's detail into the dark ones (``PER_IMAGE_KODAK.md`` of the
    natural-v4 run and its synthetic stress set, ``training/make_heldout.py --channel-gains``)."""
    c = cfg["components"]["grain"]
    lo, hi = (float(x) for x in c["amplitude"])
    if not 0 < lo <= hi:
        raise ValueError(f"grain: expected 0 < amplitude[0] <= amplitude[1] (fractions of a white), got {[lo, hi]}")
    amp = math.exp(_u(g, math.log(lo), math.log(hi)))
    s, contrast = _u(g, *c["exponent"]), float(c["contrast"])
    n = torch.stack([_tex.power_law_noise(h, w, s, g) for _ in range(3)])
    return amp * torch.exp(contrast * n - 0.5 * contrast**2), amp


def _specular(cfg, g, body: torch.Tensor) -> tuple[torch.Tensor, dict]:
    """The ``specular`` component's map ``[H, W]`` and its draws (amplitude, contrast, exponent, glossy materials):
    interface reflection of the dichromatic reflection model (Shafer, "Using color to separate reflection
    components", Color Res. Appl. 10(4), 1985), whose spectrum is the illuminant's (neutral interface reflection:
    Lee, Breneman & Schulte, "Modeling light reflection for computer color vision", IEEE PAMI 12(4), 1990).

    On each glossy material (each one glossy with ``glossy_fraction``) it is ``a t(x)`` times that material's body
    map (coverage, brightness and shading); ``t = exp(c n - c^2 / 2)`` is a log-normal texture of mean 1 from
    unit-std 1/f^s noise ``n``. It models sheen on fur, hair, skin and foliage: fine detail that adds light of the
    illuminant's colour (the same to R, G and B under a white light) whatever the material's colour, where shading
    multiplies each channel by its own level. Photographs mix both; shading alone teaches a colour-ratio prior."""
    c = cfg["components"]["specular"]
    amp = math.exp(_u(g, *map(math.log, c["amplitude"])))
    s, contrast = _u(g, *c["exponent"]), _u(g, *c["contrast"])
    glossy = (torch.rand(body.shape[0], generator=g, dtype=torch.float32) < float(c["glossy_fraction"])).float()
    h, w = body.shape[-2:]
    t = torch.exp(contrast * _tex.power_law_noise(h, w, s, g) - 0.5 * contrast**2)
    spec = amp * t * (glossy[:, None, None] * body).sum(0)
    return spec, {"amplitude": amp, "contrast": contrast, "exponent": s,
                  "glossy": [int(j) for j in torch.nonzero(glossy).flatten()]}


def generate_natural(index: int, seed: int = 0, config: dict | None = None) -> dict:
    """Scene ``index`` of the natural-statistics distribution (module docstring), factored.

    Returns ``{"maps": [J, H, W] float32 (>= 0), "spectra": [J, L] float64 (photons/s/sr/m^2/nm per unit map),
    "wavelengths_nm": [L], "illuminant": [L] (the main light, a perfect white's radiance), "meta": dict}``.
    ``meta["radii"]`` lists the drawn dead-leaves radii (for the size-law check), ``meta["dye_concentrations"]`` each
    material's Beer-Lambert concentration (1.0: undyed), ``meta["relative_grain_contrast"]`` the log-std of the
    multiplicative grain (``None``: none drawn; with it every material's map is split into three layer maps),
    ``meta["specular"]`` the sheen's draws (``None``: none drawn; else its map is the last, with the illuminant's
    spectrum).

    Example:
        >>> s = generate_natural(0, seed=1, config={"size": 32})
        >>> s["maps"].shape[-2:], s["spectra"].shape[-1]
        (torch.Size([32, 32]), 31)
    """
    cfg = config if config is not None and config.get("_checked") else natural_config(config)
    # the item's identity (-1 drew the scene of 2^64 - 1, 1.5 that of 1, "3" that of 3)
    g = torch.Generator().manual_seed(seed_for(check_seed(seed), item_index(index)))
    h = w = int(cfg["size"])
    wl = _wavelengths(cfg)
    comp = cfg["components"]
    refl, mat_kinds, dye_conc = _palette(cfg, wl, g)
    n_mat = refl.shape[0]
    lights, light_names, cct = _illuminants(cfg, wl, g, h, w)
    maps = torch.zeros(n_mat, h, w)
    maps[_ri(g, 0, n_mat - 1)] = 1.0  # the background material
    dl = comp["dead_leaves"]
    radii: list[float] = []
    if dl["enabled"]:
        radii = _paint_leaves(cfg, g, maps, _ri(g, *dl["leaves"]), float(dl["r_min_px"]),
                              float(dl["r_max_fraction"]) * h, float(dl["exponent"]))
    else:  # ablation: a few large leaves of uniform size (no scale invariance)
        radii = _paint_leaves(cfg, g, maps, 12, 0.25 * h, 0.2500001 * h, 0.0)
    depth = comp["depth_layers"]
    defocus = None
    if depth["enabled"] and _uniform(g) < depth["probability"]:
        levels = depth["defocus_diopters"]
        d_back, d_front = levels[_ri(g, 0, len(levels) - 1)], levels[_ri(g, 0, len(levels) - 1)]
        fg = torch.zeros_like(maps)
        alpha = torch.zeros(h, w)
        _paint_leaves(cfg, g, fg, _ri(g, *depth["foreground_leaves"]), 0.08 * h, 0.35 * h, 3.0, alpha=alpha)
        # the optics defocus each layer by its distance from the focus plane (550 nm PSF at the pixel pitch)
        optics, pitch = _layer_optics(float(depth["f_number"]), float(depth["focal_length_m"])), float(
            depth["pixel_size_m"])
        if d_back > 0:
            maps = optics.defocus_maps(maps, pitch, float(d_back))
        if d_front > 0:
            both = optics.defocus_maps(torch.cat([fg, alpha[None]]), pitch, float(d_front))
            fg, alpha = both[:-1], both[-1]
        maps = maps * (1 - alpha) + fg  # fg is premultiplied by its coverage
        defocus = (float(d_back), float(d_front))
    fine: list[str] = []
    fd = comp["fine_detail"]
    if fd["enabled"] and _uniform(g) < fd["probability"]:
        fine = _fine_detail(cfg, g, maps)
    cc = comp["colour_correlation"]
    s, contrast = _u(g, *cc["exponent"]), _u(g, *cc["contrast"])
    if cc["enabled"]:  # one achromatic shading field for every material
        maps = maps * torch.exp(_tex.power_law_noise(h, w, s, g) * contrast)
    else:  # ablation: the same fine detail, chromatic: a fine-scale blend towards another material
        t = _tex.colour_line_weights(h, w, s, g) * min(1.0, 2 * contrast)
        maps = maps * (1 - t) + maps.roll(1, 0) * t
    body = maps  # the materials' body-reflection maps (coverage x brightness x shading), for ``specular``
    grain_amp = None
    gr = comp["grain"]  # drawn last: with it off, every earlier draw is unchanged
    if gr["enabled"] and _uniform(g) < gr["probability"]:
        grain, grain_amp = _grain(cfg, g, h, w)
        maps = torch.cat([maps, grain])
        refl = torch.cat([refl, grain_dyes(cfg, wl)])
    rel, rel_contrast = gr["relative"], None
    if gr["enabled"] and rel["probability"] > 0 and _uniform(g) < rel["probability"]:
        # r(l) sum_k d_k(l) m_k(x) for every material: map j x layer k carries spectrum r_j d_k (exact, as the
        # layers sum to 1); the additive grain layers (after the n_mat materials) are left as they are
        rel_contrast = _u(g, *rel["contrast"])
        s_rel = _u(g, *gr["exponent"])
        mod = torch.stack([torch.exp(rel_contrast * _tex.power_law_noise(h, w, s_rel, g) - 0.5 * rel_contrast**2)
                           for _ in range(3)])
        dyes = grain_dyes(cfg, wl)
        maps = torch.cat([(maps[:n_mat, None] * mod[None]).flatten(0, 1), maps[n_mat:]])
        refl = torch.cat([(refl[:n_mat, None] * dyes[None]).flatten(0, 1), refl[n_mat:]])
    spec_meta = None
    sp = comp["specular"]  # drawn last: with probability 0 (version 5) no draw is made and the scene is unchanged
    if sp["enabled"] and sp["probability"] > 0 and _uniform(g) < sp["probability"]:
        spec, spec_meta = _specular(cfg, g, body)
        maps = torch.cat([maps, spec[None]])
        refl = torch.cat([refl, torch.ones(1, refl.shape[1], dtype=refl.dtype)])
    scale = float(cfg["mean_radiance_scale"])
    all_maps, all_spectra = [], []
    for e, m in lights:
        all_maps.append(maps if m is None else maps * m)
        all_spectra.append(refl * (e * scale)[None])
    meta = {"index": int(index), "seed": int(seed), "materials": mat_kinds, "dye_concentrations": dye_conc,
            "illuminants": light_names, "cct_k": float(cct), "radii": radii, "defocus_diopters": defocus,
            "fine_detail": fine, "shading_exponent": s, "shading_contrast": contrast, "grain_amplitude": grain_amp,
            "relative_grain_contrast": rel_contrast, "specular": spec_meta}
    return {"maps": torch.cat(all_maps), "spectra": torch.cat(all_spectra), "wavelengths_nm": wl,
            "illuminant": lights[0][0] * scale, "meta": meta}


# ------------------------------------------------------------------------------------------------ rendering

def to_scene(scene: dict, *, hfov_deg: float = 10.0, distance_m: float = 1.2, dtype=torch.float32,
             device=None):
    """The **factored** :class:`~isettorch.scene.Scene` (batch 1: ``maps [1, J, H, W]`` x ``spectra [1, J, L]``,
    no ``[L, H, W]`` cube) of a :func:`generate_natural` item, with its main light as ``illuminant_photons``.

    Every spectral integral of it is the library's: ``Scene.project`` / the :class:`~isettorch.camera.Camera`
    (a sensor projects the J spectra on its channels once, then combines the maps).

    Example:
        >>> s = to_scene(generate_natural(0, seed=1, config={"size": 32}))
        >>> s.is_factored, tuple(s.photons.shape)
        (True, (1, 31, 32, 32))
    """
    from ..scene import Scene

    meta = dict(scene["meta"])
    if meta.get("illuminants"):
        meta.setdefault("illuminant", meta["illuminants"][0])
    # validate=False: maps >= 0 (coverage x shading) and spectra >= 0 (reflectance x light) by construction
    return Scene.from_factors(scene["maps"].to(device=device, dtype=dtype)[None],
                              scene["spectra"].to(device=device, dtype=dtype)[None],
                              scene["wavelengths_nm"].to(device=device, dtype=dtype),
                              name=f"natural-{scene['meta']['seed']}-{scene['meta']['index']}", metadata=meta,
                              hfov_deg=hfov_deg, distance_m=distance_m,
                              illuminant_photons=scene["illuminant"].to(device=device, dtype=dtype)[None],
                              validate=False)


def hard_patch_indices(target: torch.Tensor, estimate: torch.Tensor, keep: float = 0.1) -> torch.Tensor:
    """Hard-patch mining (after Gharbi et al. 2016, who mine hard cases with their own metrics): indices of the
    ``keep`` fraction of patches with the largest error of a baseline ``estimate`` (e.g. Malvar-He-Cutler) against
    ``target``, both [N, C, H, W]; MSE per patch, highest first."""
    if target.shape != estimate.shape or target.dim() != 4:
        raise ValueError(f"target, estimate: expected equal shapes [N, C, H, W], got {tuple(target.shape)}, "
                         f"{tuple(estimate.shape)}")
    if not 0 < keep <= 1:
        raise ValueError(f"keep: expected a fraction in (0, 1], got {keep}")
    err = (target - estimate).pow(2).flatten(1).mean(1)
    n = max(1, int(round(keep * target.shape[0])))
    return err.argsort(descending=True)[:n]


#: training domains: linear values, power-law encoded values, or a mix (``encoded_fraction`` of the images encoded)
DOMAINS = ("linear", "encoded", "mixed")


def expose_and_encode(rgb: torch.Tensor, generator: torch.Generator, domain: str = "mixed", *,
                      encoded_fraction: float = 0.8, exposure=(0.6, 1.3), gamma=(1.8, 2.6)) -> torch.Tensor:
    """Training images in ``domain`` from linear white-balanced images ``[B, C, H, W]``: a random exposure puts the
    98th percentile at ``exposure`` (uniform), values are clipped to [0, 1] (saturation), and ``encoded`` images are
    raised to ``1 / gamma`` (gamma uniform in ``gamma``; sRGB's is ~2.2). Benchmarks such as Kodak are 8-bit encoded
    images scored as if linear, so the domain is an explicit choice; ``mixed`` encodes ``encoded_fraction``.

    An image-domain augmentation for demosaic training on the camera's noise-free rendering (its ``camera_rgb``,
    exposed by the sensor's own auto-exposure), not a second sensor model: it rescales and clips an image as a
    photograph's tone range and display encoding vary; the noisy captures of the joint models go through the
    :class:`~isettorch.sensor.Sensor` (``training/demosaic_noise.py``, :class:`~isettorch.data.PairStream`)."""
    if domain not in DOMAINS:
        raise ValueError(f"domain: expected one of {DOMAINS}, got {domain!r}")
    if rgb.dim() != 4:
        raise ValueError(f"rgb: expected [B, C, H, W], got {tuple(rgb.shape)}")
    b = rgb.shape[0]
    peak = rgb.flatten(1).quantile(0.98, dim=1).clamp_min(1e-3)
    k = (exposure[0] + (exposure[1] - exposure[0]) * torch.rand(b, generator=generator, dtype=torch.float32)) / peak
    x = (rgb * k[:, None, None, None]).clamp(0, 1)
    gam = gamma[0] + (gamma[1] - gamma[0]) * torch.rand(b, generator=generator, dtype=torch.float32)
    frac = {"linear": 0.0, "encoded": 1.0, "mixed": float(encoded_fraction)}[domain]
    use = (torch.rand(b, generator=generator, dtype=torch.float32) < frac)[:, None, None, None]
    return torch.where(use, x.clamp_min(1e-8) ** (1 / gam[:, None, None, None]), x)


class NaturalSceneDataset(torch.utils.data.Dataset):
    """``length`` factored natural scenes; item ``i`` is :func:`generate_natural` ``(i, seed, config)``."""

    def __init__(self, length: int, seed: int = 0, config: dict | None = None):
        self.length, self.seed = check_integer(length, "length", 0), check_seed(seed)
        self.config = dict(natural_config(config), _checked=True)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> dict:
        return generate_natural(dataset_index(index, self.length), self.seed, self.config)
