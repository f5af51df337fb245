"""The factored, batched camera-pair path: agreement with the module-by-module reference, bitwise batch, thread and
worker invariance, and the exact factorisation of the synthetic radiance."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from isettorch.data.camera_pairs import (
    CameraPairDataset,
    batch_loader,
    collate_pairs,
    render_pair,
    render_pairs,
)
from isettorch.data.config import SCENE_DEFAULTS, merge_config
from isettorch.data.scenes import _draw_scene, _factored_radiance, _luminance_weights, generate_scene

SCENE = {"height": 32, "width": 32, "wavelengths_nm": [400.0, 700.0, 20.0]}
IMAGES = ("noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb")


def _rel_max(a, b):
    return float(((a - b).abs().amax(dim=(1, 2, 3)) / b.abs().amax(dim=(1, 2, 3)).clamp_min(1e-30)).max())


@pytest.mark.parametrize("size,extra", [(32, {}), (26, {"two_light_probability": 1.0}),
                                        (24, {"distance_m": [0.3, 5.0]})])
def test_factored_matches_reference(size, extra):
    """Same draws, same physics: noise-free targets within float rounding of the module chain (the reference);
    the noisy raw differs only where a rounding-level change of the rate flips a Poisson or ADC draw (or re-times an
    item's Poisson stream, below).
    26 + 2 x 8 = 42 samples is not 5-smooth: the FFT buffer is padded (to 45) as in blur_fft. A range of object
    distances: the scene's distance is the one the camera's FOV was computed for (one scene sample per pixel)."""
    scene = {**SCENE, "height": size, "width": size, **extra}
    cam = {"cfa_patterns": ["RGGB", "GBRG", "GRBG", "BGGR"], "qe_variation": 1.0}
    ds = CameraPairDataset(6, seed=11, scene=scene, camera=cam)
    idx = list(range(6))
    ref = collate_pairs([render_pair(i, 11, ds.scene_config, ds.camera_config) for i in idx])
    fast = render_pairs(idx, 11, ds.scene_config, ds.camera_config)
    for k in IMAGES[:4]:
        assert _rel_max(fast[k], ref[k]) < 1e-5, k
    assert float((fast["srgb"] - ref["srgb"]).abs().max()) < 1e-4  # encoding slope is steep near 0
    # torch.poisson draws by rejection (PTRS, Hormann 1993) for large means: a rounding-level change of one rate can
    # change how many uniforms a draw takes and re-time the rest of that item's stream. Most items stay in step;
    # one that does not is another noise draw of the same image (its mean within 25 standard errors)
    differ = (fast["raw"] != ref["raw"]).double().mean(dim=(1, 2, 3))
    assert int((differ < 0.01).sum()) >= len(idx) - 1, differ
    torch.testing.assert_close(fast["raw"].double().mean(dim=(1, 2, 3)), ref["raw"].double().mean(dim=(1, 2, 3)),
                               rtol=0, atol=1e-3)
    for k, v in ref["meta"].items():
        torch.testing.assert_close(fast["meta"][k], v, rtol=1e-5, atol=0, msg=k)


def _dense_radiance(f):
    """The scene model assembled pixel by pixel (module notes of data/scenes.py), independently of the factors:
    L = k gain(x) [(1 - t) P[ia] + t P[ib]](l) (a(x) E1(l) + b(x) E2(l)), k setting the mean luminance."""
    pal = f["palette"].double()  # [K, L]
    t = f["t"].double()[..., None]
    refl = (1 - t) * pal[f["ia"]] + t * pal[f["ib"]]  # [H, W, L]
    a = torch.ones_like(f["t"]) if f["a"] is None else f["a"]
    b = torch.zeros_like(f["t"]) if f["b"] is None else f["b"]
    light = a.double()[..., None] * f["e1"] + b.double()[..., None] * f["e2"]
    cube = (f["gain"].double()[..., None] * refl * light).permute(2, 0, 1)  # [L, H, W]
    k = f["target"] / float((cube * _luminance_weights(f["wl"])[:, None, None]).sum(0).mean())
    return cube * k, f["e1"] * k


def test_factorisation_rebuilds_generate_scene():
    """sum_j maps_j(x) spectra_j(l) of generate_scene's factored scene equals the radiance assembled pixel by pixel
    (both lights cases), and its mean luminance is the drawn one."""
    cfg = merge_config({"height": 24, "width": 20, "two_light_probability": 0.5, "shadow_probability": 0.5},
                       SCENE_DEFAULTS, "scene")
    kinds, used = set(), set()
    for i in range(6):
        f = _draw_scene(i, 2, cfg, device=None, dtype=torch.float64, hfov_deg=None, size=None)
        maps, spectra, white = _factored_radiance(f, torch.float64)
        cube, white_ref = _dense_radiance(f)
        scene = generate_scene(i, 2, cfg, dtype=torch.float64)
        assert scene.is_factored
        torch.testing.assert_close(scene.maps[0], maps, rtol=0, atol=0)
        torch.testing.assert_close(scene.photons[0], cube, rtol=1e-10, atol=1e-10 * float(cube.max()))
        torch.testing.assert_close(scene.illuminant_photons[0], white_ref, rtol=1e-10, atol=0)
        assert float(scene.mean_luminance()) == pytest.approx(f["target"], rel=1e-10)
        # one term per palette colour the layout uses (with a non-zero weight) and light; unused ones left out
        t, ia, ib = f["t"], f["ia"], f["ib"]
        n_used = sum(bool(((ia == k) & (t < 1)).any() or ((ib == k) & (t > 0)).any()) for k in range(8))
        assert maps.shape[0] == (2 if f["a"] is not None else 1) * n_used
        assert bool((maps.flatten(1).amax(dim=1) > 0).all())
        kinds.add(f["a"] is not None)
        used.add(n_used)
    assert kinds == {True, False}
    assert len(used) > 1  # layouts using different numbers of colours were covered


def test_batch_equals_items_bitwise_in_any_order():
    ds = CameraPairDataset(10, seed=3, scene=SCENE)
    idx = [7, 2, 9, 2]
    batch = ds.get_batch(idx)
    per_item = collate_pairs([ds[i] for i in idx])
    assert batch["meta"]["index"].tolist() == idx
    for k in ("raw",) + IMAGES:
        assert torch.equal(batch[k], per_item[k]), k
    for k in batch["meta"]:
        assert torch.equal(batch["meta"][k], per_item["meta"][k]), k
    assert torch.equal(ds[torch.tensor([7, 2])]["raw"], batch["raw"][:2])


def test_batches_do_not_depend_on_threads():
    ds = CameraPairDataset(3, seed=1, scene={**SCENE, "height": 192, "width": 192, "wavelengths_nm":
                                             [400.0, 700.0, 50.0]})
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        a = ds.get_batch([0, 2])
        torch.set_num_threads(1)
        b = ds.get_batch([0, 2])
    finally:
        torch.set_num_threads(before)
    for k in ("raw",) + IMAGES:
        assert torch.equal(a[k], b[k]), k


def test_batch_loader_equals_item_loader_for_0_and_2_workers():
    tiny = {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]}
    ds = CameraPairDataset(7, seed=5, scene=tiny)
    ref = list(DataLoader(ds, batch_size=3, shuffle=True, generator=torch.Generator().manual_seed(4),
                          collate_fn=collate_pairs))
    for workers in (0, 2):
        got = list(batch_loader(ds, 3, shuffle=True, generator=torch.Generator().manual_seed(4),
                                num_workers=workers))
        assert [b["raw"].shape[0] for b in got] == [3, 3, 1]
        for a, b in zip(ref, got):
            assert torch.equal(a["meta"]["index"], b["meta"]["index"])
            for k in ("raw",) + IMAGES:
                assert torch.equal(a[k], b[k]), (workers, k)


def test_bad_arguments():
    ds = CameraPairDataset(4, scene={"height": 8, "width": 8, "wavelengths_nm": [400.0, 700.0, 100.0]})
    with pytest.raises(ValueError, match="method"):
        CameraPairDataset(2, method="fast")
    with pytest.raises(IndexError, match="index"):
        ds.get_batch([0, 4])
    with pytest.raises(TypeError, match="index"):
        ds[1.5]
    with pytest.raises(ValueError, match="indices"):
        ds.get_batch([])
    with pytest.raises(ValueError, match="batch_size"):
        batch_loader(ds, 0)
    with pytest.raises(ValueError, match="shuffle"):
        batch_loader(ds, 2, shuffle=True, sampler=range(4))


def test_factored_is_exact_in_float64():
    """The reordering is exact algebra: in float64 the factored path equals the module chain to ~1e-15, and the
    noise draws coincide (the same rates to the last bits do not flip any Poisson or ADC draw here)."""
    ds = CameraPairDataset(3, seed=2, scene={**SCENE, "two_light_probability": 0.5}, dtype=torch.float64)
    fast = ds.get_batch(range(3))
    ref = collate_pairs([render_pair(i, 2, ds.scene_config, ds.camera_config, dtype=torch.float64)
                         for i in range(3)])
    for k in IMAGES[:4]:
        assert fast[k].dtype == torch.float64 and _rel_max(fast[k], ref[k]) < 1e-12, k
    assert float((fast["raw"] != ref["raw"]).double().mean()) < 1e-3


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_srgb_encode_inplace_is_bitwise_the_same(dtype):
    """The in-place and ``out=`` sRGB encodings used for the targets: bitwise the out-of-place one, and IEC
    61966-2-1 (colour)."""
    import colour

    from isettorch.image import srgb_encode

    x = torch.cat([torch.linspace(0, 0.01, 101, dtype=dtype), torch.rand(1000, generator=torch.Generator()
                                                                          .manual_seed(0), dtype=dtype)])
    ref = srgb_encode(x)
    assert torch.equal(srgb_encode(x.clone(), inplace=True), ref)
    out = torch.full_like(x, float("nan"))
    keep = x.clone()
    assert srgb_encode(x, out=out) is out and torch.equal(out, ref) and torch.equal(x, keep)
    np.testing.assert_allclose(ref.double().numpy(), colour.cctf_encoding(x.double().numpy(), "sRGB"),
                               atol=1e-12 if dtype == torch.float64 else 2e-7)


def test_targets_subset_is_the_same_computation():
    """Asking for fewer targets returns exactly those keys; their values equal the full computation (bitwise when
    a colour target keeps the 6 projections; to float rounding when only camera channels are projected)."""
    scene = {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 20.0]}
    full = CameraPairDataset(4, seed=5, scene=scene).get_batch(range(4))
    srgb_only = CameraPairDataset(4, seed=5, scene=scene, targets=["srgb"]).get_batch(range(4))
    assert set(srgb_only) == {"raw", "srgb", "meta"}
    assert torch.equal(srgb_only["srgb"], full["srgb"]) and torch.equal(srgb_only["raw"], full["raw"])
    cam = CameraPairDataset(4, seed=5, scene=scene, targets=("camera_rgb",))
    got = cam.get_batch(range(4))
    assert set(got) == {"raw", "camera_rgb", "meta"}
    assert _rel_max(got["camera_rgb"], full["camera_rgb"]) < 1e-6
    assert float((got["raw"] != full["raw"]).double().mean()) < 0.01
    item = cam[2]
    assert torch.equal(item["camera_rgb"], got["camera_rgb"][2])
    ref = CameraPairDataset(4, seed=5, scene=scene, targets=("xyz",), method="reference")[1]
    assert set(ref) == {"raw", "xyz", "meta"}
    with pytest.raises(ValueError, match="targets"):
        CameraPairDataset(4, targets=("rgb",))


def test_threads_sharing_a_dataset_get_the_same_items():
    """Batches generated concurrently by threads sharing one dataset (and its caches) equal serial ones."""
    from concurrent.futures import ThreadPoolExecutor

    ds = CameraPairDataset(32, seed=9, scene={"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 30.0]})
    chunks = [list(range(i, i + 4)) for i in range(0, 32, 4)]
    serial = [CameraPairDataset(32, seed=9, scene=ds.scene_config).get_batch(c) for c in chunks]
    with ThreadPoolExecutor(4) as ex:
        threaded = list(ex.map(ds.get_batch, chunks))
    for a, b in zip(serial, threaded):
        assert torch.equal(a["raw"], b["raw"]) and torch.equal(a["meta"]["read_noise_e"], b["meta"]["read_noise_e"])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_pair_is_the_camera_applied_to_its_scene(dtype):
    """One simulator: each pair equals `Camera(scene)` of the item's camera, scene, sensor settings and noise seed
    (camera_for), for the factored scene and for its dense cube."""
    from isettorch.data.camera_pairs import camera_for

    ds = CameraPairDataset(3, seed=4, scene={**SCENE, "two_light_probability": 0.5}, dtype=dtype,
                           camera={"cfa_patterns": ["GRBG", "BGGR"], "qe_variation": 1.0})
    batch = ds.get_batch([0, 1, 2])
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for i in range(3):
        camera, scene, kw = camera_for(i, 4, ds.scene_config, ds.camera_config, dtype=dtype)
        assert scene.is_factored
        for s in (scene, scene.to_dense()):
            kwi = dict(kw)
            g = torch.Generator().manual_seed(kwi.pop("noise_seed"))
            raw = camera(s, return_intermediates=True, generator=g, **kwi).raw
            span = raw.white_level - raw.black_level
            nf = (raw.noise_free - raw.black_level) / span
            assert _rel_max(nf, batch["noise_free_raw"][i:i + 1]) < tol
            if s is scene:  # (the dense cube's auto-exposure may differ by an ulp, and a Poisson draw of another
                # mean consumes the generator differently from there on: its noise is another realisation)
                noisy = (raw.data - raw.black_level) / span
                assert float((noisy != batch["raw"][i:i + 1]).double().mean()) < 2e-3
            assert float(raw.exposure_s[0]) == pytest.approx(float(batch["meta"]["exposure_s"][i]), rel=tol)


NATURAL = {**SCENE, "generator": "natural", "natural": {"components": {"dead_leaves": {"leaves": [40, 80]}}}}


def test_a_natural_pair_is_the_camera_applied_to_its_scene():
    """scene.generator: natural: the pair is `Camera(scene)` of the natural scene built here directly from
    generate_natural (square at the scene's size + margins, to_scene, mean luminance set by the Scene), with the
    item's camera and noise seed; the scene's mean luminance (summed from its dense cube) is the drawn one."""
    from isettorch import spectral
    from isettorch.data.camera_pairs import camera_for
    from isettorch.data.natural import generate_natural, natural_config, to_scene

    ds = CameraPairDataset(2, seed=5, scene=NATURAL, camera={"cfa_patterns": ["GRBG"]})
    batch = ds.get_batch([0, 1])
    assert torch.equal(batch["raw"], collate_pairs([ds[0], ds[1]])["raw"])
    n = 32 + 2 * ds.camera_config["margin_px"]
    cfg = natural_config({**NATURAL["natural"], "size": n, "wavelengths_nm": SCENE["wavelengths_nm"]})
    for i in range(2):
        camera, scene, kw = camera_for(i, 5, ds.scene_config, ds.camera_config)
        target = scene.metadata["mean_luminance_cd_m2"]
        assert 1.0 <= target <= 5000.0 and scene.is_factored
        own = to_scene(generate_natural(i, 5, cfg), hfov_deg=float(scene.hfov_deg.reshape(())),
                       distance_m=float(scene.distance_m.reshape(()))).set_mean_luminance(target)
        torch.testing.assert_close(scene.photons, own.photons, rtol=1e-6, atol=0)
        cube = own.to_dense().photons.double()
        lum = spectral.luminance(cube, own.wavelengths_nm.double(), dim=1).mean()
        assert float(lum) == pytest.approx(target, rel=1e-4)
        g = torch.Generator().manual_seed(kw.pop("noise_seed"))
        raw = camera(own, return_intermediates=True, generator=g, **kw).raw
        span = raw.white_level - raw.black_level
        assert _rel_max((raw.noise_free - raw.black_level) / span, batch["noise_free_raw"][i:i + 1]) < 1e-5
        assert float((((raw.data - raw.black_level) / span) != batch["raw"][i:i + 1]).double().mean()) < 2e-3
    # camera_rgb mosaicked is noise_free_raw (the same chain without the CFA), and the targets are finite
    from isettorch.isp.demosaicing import mosaic

    torch.testing.assert_close(mosaic(batch["camera_rgb"], "GRBG"), batch["noise_free_raw"], rtol=1e-5, atol=1e-6)
    assert all(bool(torch.isfinite(batch[k]).all()) for k in IMAGES)
    # determinism by (seed, index): a fresh dataset gives the same item bitwise; another seed another scene
    assert torch.equal(CameraPairDataset(2, seed=5, scene=NATURAL, camera={"cfa_patterns": ["GRBG"]})[1]["raw"],
                       batch["raw"][1])
    assert not torch.equal(CameraPairDataset(2, seed=6, scene=NATURAL)[1]["camera_rgb"], batch["camera_rgb"][1])


def test_natural_generator_config_errors():
    with pytest.raises(ValueError, match="scene.generator"):
        CameraPairDataset(1, scene={"generator": "fractal"})
    with pytest.raises(ValueError, match="natural.size"):
        CameraPairDataset(1, scene={"generator": "natural", "natural": {"size": 64}})
    with pytest.raises(ValueError, match="scene.natural.*componentz"):
        CameraPairDataset(1, scene={"generator": "natural", "natural": {"componentz": {}}})
    with pytest.raises(ValueError, match="camera.optics.type"):
        CameraPairDataset(1, camera={"optics": {"type": "pinhole"}})
