"""Synthetic scenes: reflectance bounds, luminance and HDR ranges, layouts, config validation, determinism."""

import math

import numpy as np
import pytest
import torch

from isettorch import spectral
from isettorch.data import SyntheticSceneDataset, collate_scenes, generate_scene, layouts, load_config, merge_config
from isettorch.data.config import SCENE_DEFAULTS, seed_for

SMALL = {"height": 24, "width": 24, "wavelengths_nm": [400.0, 700.0, 20.0]}


def test_scene_reflectance_in_unit_interval_under_single_light():
    cfg = {**SMALL, "two_light_probability": 0.0, "shadow_probability": 0.0, "hdr_decades": [0.0, 0.0]}
    for i in range(12):
        s = generate_scene(i, 3, cfg, dtype=torch.float64)
        r = s.reflectance()
        assert float(r.min()) >= 0.0 and float(r.max()) <= 1.0 + 1e-9
        assert s.illuminant_photons.shape == (1, 16)


def test_mean_luminance_in_configured_range():
    cfg = {**SMALL, "mean_luminance_cd_m2": [20.0, 400.0]}
    values = []
    for i in range(15):
        s = generate_scene(i, 0, cfg)
        lum = float(s.mean_luminance())
        assert lum == pytest.approx(s.metadata["mean_luminance_cd_m2"], rel=1e-4)
        assert 20.0 * (1 - 1e-4) <= lum <= 400.0 * (1 + 1e-4)
        values.append(lum)
    # the draws are log-uniform on [20, 400] (module notes): Kolmogorov-Smirnov on 400 of them (a linear-uniform draw,
    # or a range's end missed, gives p < 1e-10)
    from scipy.stats import kstest

    from isettorch.data.scenes import _draw_scene

    full = merge_config(cfg, SCENE_DEFAULTS, "scene")
    targets = np.array([_draw_scene(i, 1, full, device="cpu", dtype=torch.float32, hfov_deg=None,
                                    size=(8, 8))["target"] for i in range(400)])
    assert kstest(np.log(targets / 20.0) / math.log(20.0), "uniform").pvalue > 1e-3
    assert kstest(targets, "uniform", args=(20.0, 380.0)).pvalue < 1e-6  # the test tells the two laws apart


@pytest.mark.parametrize("decades", [1.0, 3.0])
def test_hdr_illumination_spans_configured_decades(decades):
    # one reflectance everywhere (palette of 1, smooth layout): luminance max/min is the illumination range
    cfg = {**SMALL, "palette_size": 1, "layouts": {"gradients": 1.0}, "two_light_probability": 0.0,
           "shadow_probability": 0.0, "hdr_decades": [decades, decades]}
    s = generate_scene(5, 1, cfg, dtype=torch.float64)
    lum = s.luminance()
    assert math.log10(float(lum.max() / lum.min())) == pytest.approx(decades, abs=1e-9)


def test_shadow_and_two_lights_change_the_spectrum_across_the_image():
    cfg = {**SMALL, "palette_size": 1, "layouts": {"gradients": 1.0}, "two_light_probability": 1.0,
           "hdr_decades": [0.0, 0.0], "second_light_ratio": [1.0, 1.0]}
    changed = 0
    for i in range(6):
        s = generate_scene(i, 0, cfg, dtype=torch.float64)
        assert s.metadata["two_lights"]
        # with one reflectance, the ratio of two wavelengths varies across the image only if the light does
        ratio = s.photons[0, 0] / s.photons[0, -1]
        changed += float(ratio.max() / ratio.min()) > 1.05
    assert changed >= 4  # two independent random lights rarely have nearly the same spectrum


def test_layout_statistics():
    g = torch.Generator().manual_seed(0)
    # edges: piecewise-constant cells, every orientation possible
    ia, ib, t = layouts.edges(64, 64, 8, g)
    assert torch.equal(ia, ib) and float(t.abs().max()) == 0.0
    # dead leaves: many distinct leaves, some textured, coverage as the Boolean model predicts
    ia, ib, t = layouts.dead_leaves(64, 64, 8, g)
    assert ia.unique().numel() >= 3 and 0.0 <= float(t.min()) and float(t.max()) <= 1.0
    covered = []
    for _ in range(4):
        n = int(torch.randint(400, 801, (), generator=g))
        r = layouts.dead_leaves_radii(n, 2.5, 0.6 * 128, g)
        cy, cx = torch.rand(n, generator=g) * 153.6 - 12.8, torch.rand(n, generator=g) * 153.6 - 12.8
        top = layouts._paint_leaves(128, 128, cy.double(), cx.double(), r, torch.zeros(n, dtype=torch.float64),
                                    torch.ones(n, dtype=torch.float64), torch.zeros(n, dtype=torch.long), None)
        # brute force check of the run-based painter on disks, and the coverage
        yy, xx = torch.meshgrid(torch.arange(128.0), torch.arange(128.0), indexing="ij")
        d2 = (yy[None] - cy[:, None, None]) ** 2 + (xx[None] - cx[:, None, None]) ** 2
        inside = d2 <= r.float()[:, None, None] ** 2
        order = torch.arange(1, n + 1)[:, None, None]
        brute = (inside * order).amax(dim=0)
        assert torch.equal(top, brute.clamp_min(1) - 1)
        covered.append(float((brute > 0).float().mean()))
    # Boolean model: 1 - exp(-n E[pi r^2] / area) with E[r^2] = 2 ln(rmax/rmin) / (rmin^-2 - rmax^-2)
    er2 = 2 * math.log(76.8 / 2.5) / (2.5**-2 - 76.8**-2)
    expected = 1 - math.exp(-600 * math.pi * er2 / 153.6**2)
    assert sum(covered) / len(covered) == pytest.approx(expected, abs=0.04)
    # textures: energy near Nyquist (fine periodic patterns provoke aliasing)
    for _ in range(5):
        _, _, t = layouts.textures(64, 64, 8, g)
        spec = torch.fft.rfft2(t - t.mean()).abs() ** 2
        fy = torch.fft.fftfreq(64).abs()[:, None]
        fx = torch.fft.rfftfreq(64)[None, :]
        high = spec[(torch.maximum(fy, fx) >= 0.125).expand_as(spec)].sum() / spec.sum().clamp_min(1e-12)
        assert float(high) > 0.5
    # lines: thin strokes cover a minority of pixels
    _, _, cover = layouts.lines(64, 64, 8, g)
    assert 0.02 < float(cover.mean()) < 0.6


def test_dead_leaves_radius_distribution_is_scale_invariant():
    """p(r) ~ r^-3 (Lee, Mumford & Huang 2001): P(r > 2 r0) / P(r > r0) = 1/4 away from the bounds."""
    g = torch.Generator().manual_seed(0)
    rmin, rmax = 2.5, 0.6 * 128
    r = layouts.dead_leaves_radii(200000, rmin, rmax, g)
    assert float(r.min()) >= rmin and float(r.max()) <= rmax
    p5, p10 = float((r > 5).double().mean()), float((r > 10).double().mean())
    # survival function of p(r) ~ r^-3: S(r) = (r^-2 - rmax^-2) / (rmin^-2 - rmax^-2)
    assert p5 == pytest.approx((5**-2 - rmax**-2) / (rmin**-2 - rmax**-2), rel=0.02)
    assert p10 / p5 == pytest.approx((10**-2 - rmax**-2) / (5**-2 - rmax**-2), rel=0.03)


def test_determinism_by_seed_and_index():
    a = generate_scene(7, 11, SMALL)
    b = generate_scene(7, 11, SMALL)
    c = generate_scene(8, 11, SMALL)
    assert torch.equal(a.photons, b.photons) and a.metadata == b.metadata
    assert not torch.equal(a.photons, c.photons)
    assert seed_for(11, 7) != seed_for(7, 11) and seed_for(0, 1) != seed_for(1, 0)


def test_dataset_and_collate():
    ds = SyntheticSceneDataset(5, seed=2, config=SMALL)
    batch = collate_scenes([ds[0], ds[3]])
    assert batch.photons.shape == (2, 16, 24, 24)
    assert batch.metadata["index"].tolist() == [0, 3]
    assert torch.equal(batch.photons[1:], ds[3].photons)
    with pytest.raises(IndexError):
        ds[5]


def test_wavelength_grid_and_luminance_consistency():
    s = generate_scene(0, 0, SMALL, dtype=torch.float64)
    assert torch.equal(s.wavelengths_nm, spectral.default_wavelengths(400, 700, 20, dtype=torch.float64))
    lum = spectral.luminance(s.photons, s.wavelengths_nm, dim=1)
    assert torch.allclose(lum, s.luminance())


def test_config_validation(tmp_path):
    with pytest.raises(ValueError, match="scene.colour"):
        merge_config({"scene": {"colour": 1}})
    with pytest.raises(ValueError, match="scene.layouts.stars"):
        merge_config({"scene": {"layouts": {"stars": 1.0}}})
    with pytest.raises(ValueError, match="hdr_decades"):
        merge_config({"scene": {"hdr_decades": [3.0, 1.0]}})
    with pytest.raises(ValueError, match="camera.cfa_patterns"):
        merge_config({"camera": {"cfa_patterns": ["RGBW"]}})
    with pytest.raises(ValueError, match="height"):
        merge_config({"scene": {"height": [1, 2]}})
    p = tmp_path / "c.yaml"
    p.write_text("seed: 3\nscene:\n  height: 32\n  bogus: 1\n")
    with pytest.raises(ValueError, match="scene.bogus"):
        load_config(p)
    p.write_text("seed: 3\nscene:\n  height: 32\n")
    cfg = load_config(p)
    assert cfg["seed"] == 3 and cfg["scene"]["height"] == 32 and cfg["scene"]["width"] == SCENE_DEFAULTS["width"]


def test_scalar_draw_helpers_equal_torch_draws_and_state():
    from isettorch.data.config import randint_scalar, uniform01

    a, b = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
    for _ in range(50):  # interleaved with tensor draws: both generators must stay in step
        assert uniform01(a) == float(torch.rand((), generator=b, dtype=torch.float64))
        assert randint_scalar(3, 17, a) == int(torch.randint(3, 17, (), generator=b))
        assert torch.equal(torch.randn(5, generator=a), torch.randn(5, generator=b))
    u = [uniform01(a) for _ in range(1000)]
    assert 0.0 <= min(u) and max(u) < 1.0 and abs(sum(u) / len(u) - 0.5) < 0.05  # U[0, 1): mean 1/2


def test_overrides_edited_defaults_and_dtypes():
    """An audit of the generators: a config holding every key of SCENE_DEFAULTS skipped validation (an edited copy
    of the defaults with mean luminance [0, 0] gave an all-zero scene); float16 gave an all-NaN scene (the radiance
    reaches ~5e15); overriding hfov_deg moved the distance draw (1.12 m became 8.58 m), against the docstring."""
    import copy

    cfg = copy.deepcopy(SCENE_DEFAULTS)
    cfg.update(height=16, width=16, mean_luminance_cd_m2=[0.0, 0.0])
    with pytest.raises(ValueError, match="mean_luminance_cd_m2"):
        generate_scene(0, 0, cfg)
    with pytest.raises(ValueError, match="dtype: expected torch.float32 or torch.float64"):
        generate_scene(0, 0, SMALL, dtype=torch.float16)
    for i in range(3):
        free = generate_scene(i, 5, SMALL, dtype=torch.float64)
        fixed = generate_scene(i, 5, SMALL, dtype=torch.float64, hfov_deg=33.0)
        assert fixed.hfov_deg == 33.0 and fixed.distance_m == free.distance_m
        assert torch.equal(fixed.photons, free.photons)  # every other draw unchanged
