"""Random multispectral scenes: layouts x random reflectances x (mixed, HDR) illumination.

Radiance at pixel x and wavelength l (photons/s/sr/m^2/nm)::

    L(x, l) = k * gain(x) * R(x, l) * (a(x) E1(l) + b(x) E2(l))

* ``R`` in [0, 1]: a convex blend of two palette reflectances (:mod:`.layouts`, :mod:`.spectra`).
* ``E1, E2``: random illuminants, each scaled to a luminance of 1 cd/m^2 as the radiance of a perfect
  white (ISETCam's illuminant convention). ``a = 1, b = 0`` for one light; a smooth transition
  ``a = 1 - m, b = r m`` for two lights; a cast shadow ``a = 1 - s`` (soft-edged mask), ``b = q`` (skylight,
  daylight at 7000-20000 K, luminance fraction ``q``) for shadows.
* ``gain = 10^(D (f - 1/2))`` with ``f`` a smooth field spanning exactly [0, 1], so illumination spans
  ``D`` decades (``hdr_decades``).
* ``k``: sets the mean luminance to a log-uniform draw from ``mean_luminance_cd_m2``.

Every draw comes from a ``torch.Generator`` seeded by ``seed_for(seed, index)``: an item depends only on
``(seed, index)``, on any worker, rank or batch composition.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import torch

from .. import spectral
from .._autograd import tensor_cache
from .._checks import check_float_dtype, dataset_index, item_index
from ..scene import Scene
from . import layouts as _layouts
from . import spectra as _spectra
from .config import SCENE_DEFAULTS, check_integer, check_seed, merge_config, one_thread, seed_for, uniform01

__all__ = ["generate_scene", "SyntheticSceneDataset", "collate_scenes", "scene_wavelengths"]


def scene_wavelengths(cfg: dict, dtype=torch.float32, device=None) -> torch.Tensor:
    start, stop, step = cfg["wavelengths_nm"]
    return spectral.default_wavelengths(start, stop, step, dtype=dtype, device=device)


def _choice(weights: dict, g: torch.Generator) -> str:
    """A key of ``weights`` drawn with probability proportional to its weight (inverse CDF of one uniform draw,
    names in sorted order; ``torch.multinomial`` cost ~60 us per call)."""
    names = sorted(weights)
    cum = list(itertools.accumulate(float(weights[n]) for n in names))
    u = uniform01(g) * cum[-1]
    for n, c in zip(names, cum):
        if u < c and float(weights[n]) > 0:
            return n
    return [n for n in names if float(weights[n]) > 0][-1]  # u rounded up to the total


def _uniform(rng, g: torch.Generator, log: bool = False) -> float:
    if isinstance(rng, (int, float)):
        return float(rng)
    lo, hi = float(rng[0]), float(rng[1])
    u = uniform01(g)
    if log and lo > 0:
        return math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))
    return lo + u * (hi - lo)


def _smooth_field(h: int, w: int, g: torch.Generator, device, dtype, max_cycles: float = 1.5) -> torch.Tensor:
    """Sum of three random low-frequency sinusoids, rescaled to span exactly [0, 1].

    Each plane wave is separable, ``sin(A x + B y + p) = sin(A x) cos(B y + p) + cos(A x) sin(B y + p)``, so the
    sum is a rank-6 product ``[H, 6] @ [6, W]`` of 1-D factors (float64, built in numpy: a few tiny vectors)
    instead of three full-image sines.
    """
    y = np.linspace(0.0, 1.0, h)[:, None]
    x = np.linspace(0.0, 1.0, w)[None, :]
    cols, rows = [], []
    for _ in range(3):
        fr = _uniform([0.3, max_cycles], g)
        a = _uniform([0, math.pi], g)
        ph = _uniform([0, 2 * math.pi], g)
        ay, ax = 2 * math.pi * fr * math.sin(a) * y + ph, 2 * math.pi * fr * math.cos(a) * x
        cols += [np.cos(ay), np.sin(ay)]
        rows += [np.sin(ax), np.cos(ax)]
    f = torch.from_numpy(np.concatenate(cols, axis=1)) @ torch.from_numpy(np.concatenate(rows, axis=0))
    lo, hi = torch.aminmax(f)
    return ((f - lo) / (hi - lo).clamp_min(1e-6)).to(device=device, dtype=dtype)


def _white_photons(spd_energy: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Illuminant SPDs (energy) ``[..., L]`` -> photons, each scaled so a perfect white has a luminance of 1 cd/m^2
    (ISETCam's illuminant convention); any device (the batched generator's lights too)."""
    w64 = w.to(torch.float64)
    p = spectral.energy_to_photons(spd_energy.to(torch.float64), w64.to(spd_energy.device), dim=-1)
    return p / (_luminance_weights(w64) * p).sum(-1, keepdim=True)


def _luminance_weights(w: torch.Tensor) -> torch.Tensor:
    """Row vector v [L] with luminance = v . photons: 683 V(l) h c / l dl (CIE 015:2018; photons -> watts)."""
    return _luminance_weights_cached(tuple(w.tolist()), w.dtype, str(w.device)).clone()


@tensor_cache(maxsize=32)  # (outside inference mode, as the other cached spectra)
def _luminance_weights_cached(grid: tuple, dtype, device: str) -> torch.Tensor:
    w = torch.tensor(grid, dtype=torch.float64)
    ones = torch.eye(w.numel(), dtype=torch.float64)
    return spectral.luminance(ones, w, dim=-1).reshape(-1).to(dtype=dtype, device=device)


def generate_scene(index: int, seed: int = 0, config: dict | None = None, *, device=None,
                   dtype=torch.float32, hfov_deg: float | None = None, size: tuple[int, int] | None = None,
                   distance_m: float | None = None) -> Scene:
    """Scene number ``index`` of the synthetic distribution ``config`` (see :data:`SCENE_DEFAULTS`).

    Args:
        index, seed: the item's identity; the result depends only on these and the config.
        config: scene config (keys of ``SCENE_DEFAULTS``; missing keys take the defaults).
        hfov_deg, size, distance_m: overrides (used by the camera-pair dataset to match a sensor; an override is
            not drawn, the other draws are unchanged).
    Returns:
        a factored `Scene` of batch 1 (``maps [1, J, H, W]`` x ``spectra [1, J, L]``, one term per palette
        colour used and light) with ``illuminant_photons`` (the main light) and ``metadata`` describing the draw.

    Example:
        >>> s = generate_scene(3, seed=0, config={"height": 32, "width": 32})
        >>> tuple(s.photons.shape)
        (1, 31, 32, 32)
    """
    check_float_dtype(dtype)  # (float16 overflowed the radiance, about 5e15, to an all-NaN scene)
    # the item's identity (-1 drew the scene of 2^64 - 1, 1.5 that of 1, "3" that of 3)
    seed, index = check_seed(seed), item_index(index)
    with one_thread():
        return _generate_scene(index, seed, config, device=device, dtype=dtype, hfov_deg=hfov_deg, size=size,
                               distance_m=distance_m)


def _draw_scene(index, seed, config, *, device, dtype, hfov_deg, size, distance_m=None) -> dict:
    """Every random draw of scene ``(seed, index)`` (in a fixed order), before the radiance cube is assembled.

    Returns the factors of ``L(x, l) = k gain(x) R(x, l) (a(x) E1(l) + b(x) E2(l))`` (module notes):
    ``palette [K, L]`` (float64), ``ia, ib [H, W]`` (long), ``t [H, W]``, ``e1, e2 [L]`` (float64, white = 1
    cd/m^2), ``a, b [H, W]`` (None for one light), ``gain [H, W]``, ``target`` (mean luminance), ``hfov``,
    ``distance``, ``wl`` (float64), ``meta``. :func:`generate_scene` and the factored camera-pair path
    (``camera_pairs.render_pairs``) both build on it, so they draw exactly the same scene.
    """
    if size is not None and not (isinstance(size, (tuple, list)) and len(size) == 2):  # (size=16: 'cannot unpack')
        raise ValueError(f"size: expected (height, width) in pixels, got {size!r}")
    # validated every call (0.2 ms): a full config skipped it, so an edited copy of the defaults was taken unchecked;
    # at the size drawn (a camera pair's sensor + 2 x margin): the sensor's alone refused a 4 x 4 sensor whose
    # 20 x 20 scene the camera-pair config had accepted
    cfg = merge_config(config if size is None else {**(config or {}), "height": size[0], "width": size[1]},
                       SCENE_DEFAULTS, "scene")
    _check_layouts_generator(cfg)
    g = torch.Generator().manual_seed(seed_for(seed, index))
    h, wd = size if size is not None else (cfg["height"], cfg["width"])
    wl = scene_wavelengths(cfg, dtype=torch.float64)
    k = int(cfg["palette_size"])

    layout = _choice(cfg["layouts"], g)
    palette = _spectra.random_reflectances(k, wl, g, model=cfg["reflectance_model"], pca_fraction=cfg["pca_fraction"])
    ia, ib, t = _layouts.render_layout(layout, h, wd, k, g, device=device, dtype=dtype)
    kind1 = _choice(cfg["illuminants"], g)
    spd1, cct1, name1 = _spectra.random_illuminant(kind1, wl, g, cfg["cct_range_k"].get(kind1))
    e1 = _white_photons(spd1, wl)
    u_two, u_shadow = uniform01(g), uniform01(g)
    two = u_two < cfg["two_light_probability"]
    shadow = (not two) and u_shadow < cfg["shadow_probability"]
    e2 = torch.zeros_like(e1)
    cct2, name2, ratio = 0.0, "", 0.0
    a = b = None
    if two or shadow:
        y, x = torch.meshgrid(torch.arange(h, device=device, dtype=dtype),
                              torch.arange(wd, device=device, dtype=dtype), indexing="ij")
        if two:
            kind2 = _choice(cfg["illuminants"], g)
            spd2, cct2, name2 = _spectra.random_illuminant(kind2, wl, g, cfg["cct_range_k"].get(kind2))
            ratio = _uniform(cfg["second_light_ratio"], g, log=True)
        else:
            spd2, cct2, name2 = _spectra.random_illuminant("daylight", wl, g, (7000.0, 20000.0))
            ratio = _uniform(cfg["shadow_ambient"], g, log=True)
        e2 = _white_photons(spd2, wl)
        ang = _uniform([0, 2 * math.pi], g)
        py, px = _uniform([0.2 * h, 0.8 * h], g), _uniform([0.2 * wd, 0.8 * wd], g)
        signed = (x - px) * math.cos(ang) + (y - py) * math.sin(ang)
        if two:  # smooth transition between the lights over 10-60 % of the image
            width = _uniform([0.1, 0.6], g) * max(h, wd)
            m = torch.sigmoid(signed / (width / 4))
            a, b = 1 - m, ratio * m
        else:  # shadow: half-plane or disk, soft edge 0.3-3 px (penumbra)
            soft = _uniform([0.3, 3.0], g)
            if float(torch.rand((), generator=g, dtype=torch.float32)) < 0.5:
                rad = _uniform([0.15, 0.45], g) * min(h, wd)
                signed = rad - torch.sqrt((x - px) ** 2 + (y - py) ** 2 + 1e-12)
            s = torch.sigmoid(signed / soft)
            a, b = 1 - s, torch.full_like(s, ratio)
    decades = _uniform(cfg["hdr_decades"], g)
    # 10^(D (f - 1/2)) as exp(ln 10 D (f - 1/2)) (one exp, much faster than a float power on CPU)
    gain = torch.exp((_smooth_field(h, wd, g, device, dtype) - 0.5).mul_(math.log(10) * decades)) if decades > 0 \
        else torch.ones(h, wd, device=device, dtype=dtype)
    target = _uniform(cfg["mean_luminance_cd_m2"], g, log=True)
    # drawn even where overridden, so an override leaves the other draws as they are (the docstring's promise)
    hfov, distance = _uniform(cfg["hfov_deg"], g), _uniform(cfg["distance_m"], g)
    hfov = hfov_deg if hfov_deg is not None else hfov
    distance = distance_m if distance_m is not None else distance
    meta = {"index": int(index), "seed": int(seed), "layout": layout, "illuminant": name1, "cct_k": cct1,
            "illuminant2": name2, "cct2_k": cct2, "light2_ratio": ratio, "two_lights": two, "shadow": shadow,
            "hdr_decades": decades, "mean_luminance_cd_m2": target}
    return {"palette": palette, "ia": ia, "ib": ib, "t": t, "e1": e1, "e2": e2, "a": a, "b": b, "gain": gain,
            "target": target, "hfov": hfov, "distance": distance, "wl": wl, "meta": meta}


def _factored_radiance(f: dict, dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The scene of :func:`_draw_scene` factors as ``L(x, l) = sum_j maps_j(x) spectra_j(l)``:

    ``R = (1 - t) P[ia] + t P[ib]`` is linear in the K palette reflectances and the light is ``a E1 + b E2``, so
    ``maps = gain [(1 - t) 1(ia = k) + t 1(ib = k)] x (a | b)`` ``[J, H, W]`` (J = K for one light, 2K for two)
    and ``spectra = scale P_k E1 | scale P_k E2`` ``[J, L]`` (float64), with ``scale`` setting the mean luminance
    (CIE 015:2018 luminance weights); terms whose map is 0 everywhere are left out (J <= K, 2K). Returns
    ``(maps, spectra, white [L])`` (white: light 1, scaled).
    """
    t, ia, ib = f["t"], f["ia"], f["ib"]
    h, w = t.shape
    k = f["palette"].shape[0]
    coef = torch.zeros(k, h * w, dtype=dtype, device=t.device)
    coef.scatter_add_(0, ia.reshape(1, -1), (1 - t).reshape(1, -1).to(dtype))
    coef.scatter_add_(0, ib.reshape(1, -1), t.reshape(1, -1).to(dtype))
    coef.mul_(f["gain"].reshape(1, -1).to(dtype))
    pal = f["palette"].to(torch.float64)
    if f["a"] is not None:
        maps = torch.empty(2 * k, h * w, dtype=dtype, device=t.device)
        torch.mul(coef, f["a"].reshape(1, -1).to(dtype), out=maps[:k])
        torch.mul(coef, f["b"].reshape(1, -1).to(dtype), out=maps[k:])
        spectra = torch.cat([pal * f["e1"], pal * f["e2"]])
    else:
        maps, spectra = coef, pal * f["e1"]
    # mean luminance = sum_j (v . spectra_j) mean_x maps_j, in float64 (per-map sums accumulated in the maps'
    # dtype: torch's cascade sum, ~1e-7 relative in float32, 5x faster than converting every pixel to float64)
    lum = spectra @ _luminance_weights(f["wl"])
    mean_lum = float((maps.sum(dim=1).to(torch.float64).cpu() * lum).sum()) / (h * w)
    scale = f["target"] / max(mean_lum, torch.finfo(dtype).tiny)
    # Terms whose map is 0 everywhere (palette entries the layout does not use: ~40 % of them, as most layouts
    # but dead leaves use 2-4 of the 8 colours) add exactly 0 to the radiance: dropped, so the optics do fewer FFTs.
    used = (maps.amax(dim=1) > 0).cpu()  # maps >= 0
    if not bool(used.all()):
        idx = used.nonzero().reshape(-1)
        maps, spectra = maps.index_select(0, idx.to(maps.device)), spectra.index_select(0, idx)
    return maps.reshape(-1, h, w), spectra * scale, f["e1"] * scale


def _check_layouts_generator(cfg: dict) -> None:
    """These scenes are the layouts generator's: ``scene.generator: natural`` would be ignored."""
    if cfg["generator"] != "layouts":
        raise ValueError(f"scene.generator: generate_scene and SyntheticSceneDataset draw the 'layouts' generator, got "
                         f"{cfg['generator']!r} (natural scenes: isettorch.data.natural.generate_natural, "
                         f"NaturalSceneDataset)")


def _generate_scene(index, seed, config, *, device, dtype, hfov_deg, size, distance_m=None) -> Scene:
    f = _draw_scene(index, seed, config, device=device, dtype=dtype, hfov_deg=hfov_deg, size=size,
                    distance_m=distance_m)
    maps, spectra, white = _factored_radiance(f, dtype)
    wl_t = f["wl"].to(device=device, dtype=dtype)
    # factored (maps x spectra: the optics transform J maps, not L bands); validate=False: non-negative and
    # finite by construction (reflectance in [0, 1] x positive lights)
    return Scene.from_factors(maps[None], spectra.to(device=device, dtype=dtype)[None], wl_t,
                              name=f"synthetic-{seed}-{index}", metadata=f["meta"], hfov_deg=f["hfov"],
                              distance_m=f["distance"], illuminant_photons=white.to(device=device, dtype=dtype)[None],
                              validate=False)


class SyntheticSceneDataset(torch.utils.data.Dataset):
    """A map-style dataset of ``length`` random scenes; item ``i`` depends only on ``(seed, i)``.

    Args:
        length: number of items.
        seed: dataset seed.
        config: scene config (see :data:`isettorch.data.config.SCENE_DEFAULTS`); validated.
        dtype, device: where scenes are built (CPU is right inside DataLoader workers).

    Example:
        >>> ds = SyntheticSceneDataset(10, seed=1, config={"height": 16, "width": 16})
        >>> loader = torch.utils.data.DataLoader(ds, batch_size=4, collate_fn=collate_scenes)
        >>> next(iter(loader)).photons.shape
        torch.Size([4, 31, 16, 16])
    """

    def __init__(self, length: int, seed: int = 0, config: dict | None = None, *, dtype=torch.float32,
                 device=None):
        self.length, self.seed = check_integer(length, "length", 0), check_seed(seed)
        self.config = merge_config(config, SCENE_DEFAULTS, "scene")
        _check_layouts_generator(self.config)
        self.dtype = dtype
        self.device = device

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> Scene:
        index = dataset_index(index, self.length)  # (a 0-d tensor index, as a sampler may give, is an int)
        return generate_scene(index, self.seed, self.config, device=self.device, dtype=self.dtype)


def collate_scenes(scenes: list[Scene]) -> Scene:
    """Batch scenes with `Scene.cat`; per-item metadata is kept as ``metadata["items"]`` (a list of dicts)
    and the numeric fields also as [B] tensors (``metadata["cct_k"]`` ...)."""
    batch = Scene.cat(scenes)
    items = [s.metadata for s in scenes]
    meta = {"items": items}
    for key in ("index", "cct_k", "hdr_decades", "mean_luminance_cd_m2"):
        meta[key] = torch.tensor([m[key] for m in items], dtype=torch.float64 if key != "index" else torch.long)
    return batch.replace(metadata=meta, name="synthetic-batch")
