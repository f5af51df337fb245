"""The scene sources of :mod:`training.codesign` (issue 36): a source is ``fn(k, n, size, camera, cfg, seed) ->
(maps [n, J, size, size], reflectance [n, J, L])`` on the camera's wavelength grid, batch ``k`` a function of (seed,
k, cfg) only; and the linear sRGB targets of a batch under D65."""

from __future__ import annotations

from pathlib import Path

import torch

from isettorch.data.config import seed_for
from isettorch.design import DesignCamera, linear_srgb_of_reflectance
from training import common


def _reflectance_of(spectra: torch.Tensor, white: torch.Tensor) -> torch.Tensor:
    """Reflectance = radiance spectra / the light's white radiance (single-light scenes)."""
    return spectra / white[:, None, :].clamp_min(torch.finfo(white.dtype).tiny)


def source_layouts(k: int, n: int, size: int, camera: DesignCamera, cfg: dict, seed: int,
                   split: str = "train"):
    """PairStream's scenes (:func:`isettorch.data.batched.draw_layout_scenes`), one light, no shadows or HDR."""
    from isettorch.data.batched import draw_layout_scenes
    from isettorch.data.config import SCENE_DEFAULTS, merge_config

    lo, hi, step = camera.config["scene"]["wavelengths_nm"]
    scene_cfg = merge_config({"two_light_probability": 0.0, "shadow_probability": 0.0, "hdr_decades": [0.0, 0.0],
                              "height": size, "width": size, "wavelengths_nm": [lo, hi, step],
                              **cfg["data"]["scene"]}, SCENE_DEFAULTS, "scene")
    g = torch.Generator().manual_seed(seed_for(seed, k, stream=0))
    drawn = draw_layout_scenes(n, g, scene_cfg, size=(size, size), device="cpu", dtype=torch.float32)
    return drawn["maps"], _reflectance_of(drawn["spectra"], drawn["white"]).float()


def source_natural(k: int, n: int, size: int, camera: DesignCamera, cfg: dict, seed: int,
                   split: str = "train"):
    """:func:`isettorch.data.natural.generate_natural` scenes under one daylight (their reflectances)."""
    from isettorch.data.natural import generate_natural, natural_config

    lo, hi, step = camera.config["scene"]["wavelengths_nm"]
    ncfg = natural_config(dict(cfg["data"]["natural"], size=size, wavelengths_nm=[lo, hi, step]))
    ncfg["components"]["illuminant"]["enabled"] = False  # one 6500 K daylight: spectra / white = reflectance
    items = [generate_natural(k * n + i, seed, ncfg) for i in range(n)]
    j = max(it["maps"].shape[0] for it in items)

    def pad(t, dim_size):
        return torch.cat([t, t.new_zeros(dim_size - t.shape[0], *t.shape[1:])]) if t.shape[0] < dim_size else t

    maps = torch.stack([pad(it["maps"], j) for it in items])
    refl = torch.stack([pad(_reflectance_of(it["spectra"][None], it["illuminant"][None])[0], j) for it in items])
    return maps, refl.float()


def source_photos(k: int, n: int, size: int, camera: DesignCamera, cfg: dict, seed: int,
                  split: str = "train"):
    """Random ``size`` crops (and flips) of the photographs in ``data.folder``, lifted to spectra: ``split``
    ``'train'`` from all but every fifth photograph (by name), ``'val'`` from those (the validation crops came from the
    training photographs, under a card that called them held out). The other sources draw fresh scenes per seed."""
    import numpy as np

    from isettorch.data.photos import lift_srgb
    from isettorch.isp.evaluation import load_images

    folder = cfg["data"]["folder"]
    if not folder:
        raise ValueError("data.folder: the photos source needs a folder of 8-bit RGB .png/.tif/.jpg photographs")
    cache = source_photos.__dict__.setdefault("cache", {})
    if folder not in cache:
        photos = load_images(common_path(folder))
        common.refuse_test_images(photos, "data.folder")  # trained and validated on: never a test set
        cache[folder] = photos
    photos = sorted(cache[folder], key=lambda item: item[0])
    if len(photos) < 2:
        raise ValueError(f"data.folder: the photos source needs at least 2 photographs (every fifth is held out for "
                         f"validation), {folder!r} has {len(photos)}")
    held = {i for i in range(len(photos)) if i % 5 == 4} or {len(photos) - 1}
    if split not in ("train", "val"):
        raise ValueError(f"split: expected 'train' or 'val', got {split!r}")
    photos = [ph for i, ph in enumerate(photos) if (i in held) == (split == "val")]
    g = torch.Generator().manual_seed(seed_for(seed, k, stream=0))
    maps, refl = [], None
    for _ in range(n):
        name, arr = photos[int(torch.randint(len(photos), (), generator=g))]
        h, w = arr.shape[:2]
        if min(h, w) < size:
            raise ValueError(f"data.size: {name} is {w} x {h}, smaller than the crop {size}")
        y, x = (int(torch.randint(d - size + 1, (), generator=g)) for d in (h, w))
        crop = np.ascontiguousarray(arr[y:y + size, x:x + size])
        if float(torch.rand((), generator=g)) < 0.5:
            crop = np.ascontiguousarray(crop[:, ::-1])
        lifted = lift_srgb(crop, camera.wavelengths_nm)
        maps.append(lifted["maps"].float())
        refl = lifted["reflectance"].float()
    return torch.stack(maps), refl[None].expand(n, -1, -1)


def common_path(folder: str) -> Path:
    from isettorch.paths import data_path

    return data_path(folder)


SOURCES = {"layouts": source_layouts, "natural": source_natural, "photos": source_photos}


def targets(maps: torch.Tensor, reflectance: torch.Tensor, camera: DesignCamera) -> torch.Tensor:
    """Linear sRGB ``[B, 3, H, W]`` of the scene under D65 (white = 1): each material's colour
    (:func:`isettorch.design.linear_srgb_of_reflectance`) weighted by its map."""
    rgb = linear_srgb_of_reflectance(reflectance.double(), camera.wavelengths_nm,
                                     camera.config["scene"]["illuminant"])  # [B, J, 3]
    return torch.einsum("bjc,bjhw->bchw", rgb.to(maps.dtype), maps)
