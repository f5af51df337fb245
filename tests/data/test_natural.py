"""The natural-statistics scene generator (isettorch.data.natural, textures, statistics, photos): determinism by
(seed, index), each component's statistics against its specification, and the lifting of photos to spectra."""

from __future__ import annotations

import math

import colour
import numpy as np
import pytest
import torch
from PIL import Image

from isettorch import spectral
from isettorch.data import natural as nat
from isettorch.data import spectra as sp
from isettorch.data.layouts import dead_leaves_radii
from isettorch.data.photos import PhotoSceneDataset
from isettorch.metrics import image_statistics as st
from isettorch.scene import textures as tex

WL = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
SMALL = {"size": 48, "components": {"dead_leaves": {"leaves": [40, 80]}}}


def test_determinism_by_seed_and_index():
    a = nat.generate_natural(3, seed=7, config=SMALL)
    nat.generate_natural(0, seed=7, config=SMALL)  # other draws in between change nothing
    b = nat.generate_natural(3, seed=7, config=SMALL)
    assert torch.equal(a["maps"], b["maps"]) and torch.equal(a["spectra"], b["spectra"])
    c = nat.generate_natural(4, seed=7, config=SMALL)
    d = nat.generate_natural(3, seed=8, config=SMALL)
    assert a["meta"]["radii"] != c["meta"]["radii"] and a["meta"]["radii"] != d["meta"]["radii"]  # other draws
    ds = nat.NaturalSceneDataset(5, seed=7, config=SMALL)
    assert torch.equal(ds[3]["maps"], a["maps"])
    assert (a["maps"] >= 0).all() and (a["spectra"] >= 0).all() and torch.isfinite(a["maps"]).all()


def test_config_errors_name_the_key():
    with pytest.raises(ValueError, match="'components.dead_leaves.radius'"):
        nat.natural_config({"components": {"dead_leaves": {"radius": 3}}})
    with pytest.raises(ValueError, match="disable.*'fog'"):
        nat.natural_config(disable=("fog",))
    cfg = nat.natural_config(disable=("fine_detail", "depth_layers"))
    assert not cfg["components"]["fine_detail"]["enabled"] and cfg["components"]["palette"]["enabled"]


def test_dead_leaves_size_law_exponent():
    """The radii drawn for the scenes follow p(r) ~ r^-3 (Lee, Mumford & Huang 2001): MLE within 0.1."""
    cfg = nat.natural_config({"size": 64}, disable=("depth_layers", "fine_detail", "textured_leaves"))
    radii = []
    for i in range(6):
        radii += nat.generate_natural(i, seed=1, config=cfg)["meta"]["radii"]
    lo, hi = cfg["components"]["dead_leaves"]["r_min_px"], cfg["components"]["dead_leaves"]["r_max_fraction"] * 64
    alpha = st.power_law_exponent_mle(radii, lo, hi)
    assert len(radii) > 900 and abs(alpha - 3.0) < 0.1, (len(radii), alpha)


def test_power_law_mle_recovers_known_exponents():
    g = torch.Generator().manual_seed(0)
    r = dead_leaves_radii(40000, 2.0, 200.0, g).numpy()
    assert st.power_law_exponent_mle(r, 2.0, 200.0) == pytest.approx(3.0, abs=0.03)
    u = np.random.default_rng(0).uniform(size=40000)  # alpha = 2 by inverse CDF of the truncated law
    r2 = 1.0 / (1.0 - u * (1 - 1 / 50.0))
    assert st.power_law_exponent_mle(r2, 1.0, 50.0) == pytest.approx(2.0, abs=0.03)


@pytest.mark.parametrize("exponent", [0.8, 1.0, 1.5])
def test_texture_spectrum_slope(exponent):
    """1/f^s amplitude -> power-spectrum slope -2s (Field 1987), within 0.15 on the mean of 4 fields."""
    g = torch.Generator().manual_seed(1)
    slopes = [st.power_spectrum_slope(tex.power_law_noise(128, 128, exponent, g), f_range=(4.0, 0.4))
              for _ in range(4)]
    assert np.mean(slopes) == pytest.approx(-2 * exponent, abs=0.15)
    x = tex.power_law_noise(64, 96, exponent, g)
    assert float(x.mean()) == pytest.approx(0, abs=1e-5) and float(x.std()) == pytest.approx(1, abs=1e-5)


def test_spectrum_slope_of_white_noise_and_warped_grating():
    g = torch.Generator().manual_seed(2)
    assert st.power_spectrum_slope(torch.randn(128, 128, generator=g)) == pytest.approx(0.0, abs=0.15)
    t = tex.warped_grating(128, 128, 0.1, 0.3, 0.0, g)  # no warp: a pure grating of 0.1 cycles/pixel
    f, p = st.radial_power_spectrum(t)
    assert abs(f[np.argmax(p)] - 0.1) < 1.5 / 128
    assert 0 <= float(t.min()) and float(t.max()) <= 1


def test_colour_line_weights_make_colours_on_a_line():
    """A colour-line texture blends two materials: its pixels' colours are collinear (rank 1 after centring)."""
    g = torch.Generator().manual_seed(3)
    t = tex.colour_line_weights(32, 32, 1.2, g)
    ca, cb = torch.tensor([0.2, 0.5, 0.1]), torch.tensor([0.7, 0.3, 0.6])
    rgb = (1 - t).reshape(-1, 1) * ca + t.reshape(-1, 1) * cb
    s = torch.linalg.svdvals(rgb - rgb.mean(0))
    assert float(s[1] / s[0]) < 1e-5 and float(t.std()) > 0.1


def test_colour_correlation_makes_fine_detail_achromatic():
    """On: the 1/f shading multiplies every material by the same factor at a pixel (intensity only, chromaticity
    kept). Off: the same field changes the pixel's colour. Compared with the identical scene at zero contrast."""
    sens = sp.camera_sensitivities("Nikon 5100 (NPL)", WL)

    def rgb(contrast, *off):
        cfg = nat.natural_config({"size": 48, "components": {"colour_correlation": {"contrast": [contrast] * 2}}},
                                 disable=(*off, "grain"))  # grain (unshaded, per layer) is chromatic on purpose
        scene = nat.to_scene(nat.generate_natural(2, 0, cfg), dtype=torch.float64)
        return scene.project(sens.T)[0]  # the library's projection of the factored scene (no white balance:
        # the per-channel ratio below does not need it)

    for off in ((), ("colour_correlation",)):
        base, detail = rgb(0.0, *off), rgb(0.3, *off)
        ok = base.min(0).values > 1e-3
        ratio = (detail / base.clamp_min(1e-12))[:, ok]  # [3, N]
        spread = float((ratio.std(0) / ratio.mean(0)).mean())  # across channels, per pixel
        if not off:
            assert spread < 1e-4 and float(ratio[1].std()) > 0.1  # achromatic, and really modulating
        else:
            assert spread > 0.01


def test_detail_ratio_exponent_reads_ratio_and_difference_detail():
    """Smoothly varying colours with fine texture: multiplied into every channel (shading) gives exponent 1, added
    alike to every channel gives 0, half of each in between; a per-image scale changes nothing; too few usable
    windows is an error."""
    g = torch.Generator().manual_seed(0)
    yy, xx = torch.meshgrid(torch.arange(130.0), torch.arange(130.0), indexing="ij")
    imgs = {"mult": [], "add": [], "both": []}
    for _ in range(6):
        ph = torch.rand(3, 2, generator=g, dtype=torch.float64) * 6.28
        level = torch.stack([0.45 + 0.4 * torch.sin(xx / 37 + ph[c, 0]) * torch.cos(yy / 29 + ph[c, 1])
                             for c in range(3)])  # [3, H, W], 0.05-0.85, nearly constant over 16 px
        n = torch.randn(130, 130, generator=g, dtype=torch.float64)
        imgs["mult"].append(level * (1 + 0.1 * n))
        imgs["add"].append(level + 0.05 * n)
        imgs["both"].append(level * (1 + 0.05 * n) + 0.025 * n)
    b_mult, count = st.detail_ratio_exponent(imgs["mult"])
    assert abs(b_mult - 1.0) < 0.02 and count > 200
    assert abs(st.detail_ratio_exponent(imgs["add"])[0]) < 0.02
    assert 0.2 < st.detail_ratio_exponent(imgs["both"])[0] < 0.8
    assert st.detail_ratio_exponent([3.0 * i for i in imgs["mult"]])[0] == pytest.approx(b_mult, abs=1e-9)
    with pytest.raises(ValueError, match="images"):
        st.detail_ratio_exponent([torch.full((3, 40, 40), 0.5, dtype=torch.float64)])


def test_specular_lowers_the_detail_ratio_exponent_of_rendered_scenes():
    """Rendered to linear sRGB through the library's projection (white-balanced, as benchmarks/scene_stats.py),
    version-5 scenes are a colour-ratio world (exponent near 1: shading multiplies every channel); with the
    ``specular`` sheen in every scene the exponent falls (illuminant-coloured detail is added alike to R, G, B)."""
    from isettorch.isp.colour import XYZ_TO_LINEAR_SRGB

    m = (torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ spectral.cmfs(WL, dtype=torch.float64)
         * spectral.wavelength_weights(WL)[None])

    def beta(probability):
        cfg = nat.natural_config({"size": 96, "components": {"specular": {"probability": probability}}})
        out = []
        for i in range(12):
            sc = nat.to_scene(nat.generate_natural(i, 4, cfg), dtype=torch.float64)
            out.append(sc.project(m.T)[0] / (sc.illuminant_photons[0] @ m.T)[:, None, None])
        return st.detail_ratio_exponent(out)[0]

    b5, bs = beta(0.0), beta(1.0)
    assert 0.9 < b5 < 1.1 and bs < b5 - 0.12  # 0.92 -> 0.75 here; 0.97 -> 0.70-0.77 on 2 x 32 scenes of 128 px


def test_recovery_reflectances_round_trip_to_srgb():
    """colour.recovery's basis: the reflectance of a linear sRGB triplet has that sRGB under D65 (to 0.01)."""
    rgb = torch.tensor([[0.2, 0.5, 0.1], [0.8, 0.1, 0.3], [0.5, 0.5, 0.5]], dtype=torch.float64)
    basis = sp.srgb_basis_spectra(torch.arange(380.0, 781.0, 5.0, dtype=torch.float64))
    for c, r in zip(rgb, rgb @ basis):
        sd = colour.SpectralDistribution(r.numpy(), np.arange(380.0, 781.0, 5.0))
        xyz = colour.sd_to_XYZ(sd, illuminant=colour.SDS_ILLUMINANTS["D65"]) / 100
        back = colour.XYZ_to_RGB(xyz, "sRGB", apply_cctf_encoding=False)
        np.testing.assert_allclose(back, c.numpy(), atol=0.01)
    g = torch.Generator().manual_seed(0)
    r = sp.recovery_reflectances(200, WL, g)
    assert r.shape == (200, 31) and float(r.min()) >= 0 and float(r.max()) <= 1


def test_fine_detail_puts_energy_near_nyquist():
    """Gratings and lines at 0.15-0.7 cycles/pixel: more power above 0.25 cycles/pixel than without them."""
    def hf(cfg):
        out = []
        for i in range(4):
            m = nat.generate_natural(i, 5, cfg)["maps"].sum(0)
            f, p = st.radial_power_spectrum(m)
            out.append(p[f > 0.25].sum() / p.sum())
        return np.mean(out)

    base = {"size": 64, "components": {"fine_detail": {"probability": 1.0, "items": [3, 3]}}}
    # the leaves' own fine structure aside (few large flat leaves: the ablation form of dead_leaves)
    others = ("dead_leaves", "textured_leaves", "depth_layers", "colour_correlation")
    with_detail, without = hf(nat.natural_config(base, disable=others)), hf(nat.natural_config(
        base, disable=others + ("fine_detail",)))
    assert with_detail > 3 * without, (with_detail, without)


def test_depth_layers_defocus_with_the_library_psf():
    optics = nat._layer_optics(2.0, 0.004)  # the layers' lens; the optics blur each layer (defocus_maps)
    point = torch.zeros(1, 65, 65)
    point[0, 32, 32] = 1.0
    blurred = optics.defocus_maps(point, 1.4e-6, 2.0)
    assert float(blurred.sum()) == pytest.approx(1.0, abs=1e-5)
    sharp = optics.defocus_maps(point, 1.4e-6, 0.0)
    assert float(blurred.max()) < 0.5 * float(sharp.max())  # defocus spreads the PSF
    cfg = {"size": 48, "components": {"depth_layers": {"probability": 1.0, "defocus_diopters": [2.0]}}}
    s = nat.generate_natural(0, 0, cfg)
    assert s["meta"]["defocus_diopters"] == (2.0, 2.0)


def test_to_scene_is_factored_and_sums_maps_times_spectra():
    """to_scene gives a factored Scene (no cube) whose radiance is sum_j map_j(x) spectrum_j(l), summed here
    independently in float64; its projection (Scene.project, what the camera uses) is the integral of that cube."""
    s = nat.generate_natural(1, 2, SMALL)
    scene = nat.to_scene(s, dtype=torch.float64, hfov_deg=3.0, distance_m=2.0)
    assert scene.is_factored and scene.maps.shape == (1, *s["maps"].shape)
    cube = (s["maps"].double()[:, None] * s["spectra"][:, :, None, None]).sum(0)  # [L, H, W]
    torch.testing.assert_close(scene.photons[0], cube, rtol=1e-12, atol=0)
    sens = sp.camera_sensitivities("Nikon 5100 (NPL)", WL)
    w = (sens * spectral.wavelength_weights(WL)[None]).T  # [L, 3] photon counting with the band widths
    dense = torch.einsum("lc,lhw->chw", w, cube)
    torch.testing.assert_close(nat.to_scene(s, dtype=torch.float64).project(w)[0], dense, rtol=1e-10, atol=0)
    assert float(scene.hfov_deg.reshape(())) == pytest.approx(3.0) and float(scene.distance_m.reshape(())) == 2.0
    torch.testing.assert_close(scene.illuminant_photons[0], s["illuminant"])
    assert scene.metadata["illuminant"] == s["meta"]["illuminants"][0]


def test_hard_patch_indices():
    t = torch.zeros(5, 3, 4, 4)
    e = t.clone()
    for i, v in enumerate([0.1, 0.5, 0.0, 0.3, 0.2]):
        e[i] += v
    assert nat.hard_patch_indices(t, e, keep=0.4).tolist() == [1, 3]
    with pytest.raises(ValueError, match="keep"):
        nat.hard_patch_indices(t, e, keep=0)


def test_photo_folder_lifts_to_spectra(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    Image.fromarray(img).save(tmp_path / "a.png")
    ds = PhotoSceneDataset(tmp_path, size=32, length=3, seed=1)
    item = ds[1]
    assert item["maps"].shape == (3, 32, 32) and item["spectra"].shape == (3, 31)
    assert torch.equal(ds[1]["maps"], item["maps"])
    # the maps are the decoded linear sRGB values of the crop (IEC 61966-2-1)
    y, x = item["meta"]["crop_yx"]
    enc = img[y:y + 32, x:x + 32].astype(np.float64) / 255
    lin = np.where(enc <= 0.04045, enc / 12.92, ((enc + 0.055) / 1.055) ** 2.4).transpose(2, 0, 1)
    m = item["maps"].double().numpy()
    assert np.allclose(m, lin, atol=1e-6) or np.allclose(m, lin[..., ::-1], atol=1e-6)
    with pytest.raises(ValueError, match="size.*a.png.*smaller"):
        PhotoSceneDataset(tmp_path, size=64)[0]
    with pytest.raises(ValueError, match="folder"):
        PhotoSceneDataset(tmp_path / "missing")


def test_statistics_references():
    """Gaussian white noise: gradient kurtosis 3; identical channels: gradient correlation 1."""
    g = torch.Generator().manual_seed(4)
    x = torch.randn(256, 256, generator=g, dtype=torch.float64)
    # differences of iid Gaussians are Gaussian: kurtosis 3 (standard error ~ sqrt(24 / N) ~ 0.007)
    assert st.gradient_kurtosis(x) == pytest.approx(3.0, abs=0.05)
    rgb = torch.stack([x, 2 * x + 1, torch.randn(256, 256, generator=g, dtype=torch.float64)])
    assert st.cross_channel_gradient_correlation(rgb, 0, 1) == pytest.approx(1.0, abs=1e-12)
    assert abs(st.cross_channel_gradient_correlation(rgb, 0, 2)) < 0.02
    with pytest.raises(ValueError, match="image"):
        st.gradient_kurtosis(torch.ones(16, 16))
    assert math.isfinite(st.power_spectrum_slope(x))


def test_shipped_generator_config_is_the_defaults():
    """configs/synth/natural.yaml documents NATURAL_DEFAULTS: it loads without error and equals them."""
    from pathlib import Path

    import yaml

    path = Path(__file__).resolve().parents[2] / "configs" / "synth" / "natural.yaml"
    cfg = yaml.safe_load(path.read_text())
    assert nat.natural_config(cfg) == nat.NATURAL_DEFAULTS

    def keys(d, prefix=""):  # every key it documents, nested (a key left out passed: the defaults filled it)
        return {prefix + k for k in d} | {x for k, v in d.items() if isinstance(v, dict) for x in keys(v, f"{k}.")}

    assert keys(cfg) == keys(nat.NATURAL_DEFAULTS)


def test_mixed_illuminants_blend_two_lights_smoothly():
    """Two lights: the maps split into two halves (light 1, light 2) whose per-pixel shares are the same for every
    material (the light field is spatial, not material-dependent), span a real range and vary smoothly."""
    cfg = {"size": 48, "components": {"illuminant": {"mixed_probability": 1.0}}}
    s = nat.generate_natural(0, 3, cfg)
    k = s["maps"].shape[0] // 2
    assert len(s["meta"]["illuminants"]) == 2 and s["spectra"].shape[0] == 2 * k
    m1, m2 = s["maps"][:k].double(), s["maps"][k:].double()
    total = m1 + m2
    ok = total > 1e-3
    share = torch.where(ok, m1 / total.clamp_min(1e-12), torch.nan)
    present = ok.sum(0) >= 2  # pixels where two or more materials are seen (edges, blends, textures)
    assert int(present.sum()) > 50
    spread = torch.nan_to_num(share, nan=-1).amax(0) - torch.nan_to_num(share, nan=2).amin(0)
    assert float(spread[present].max()) < 1e-5
    field = torch.nanmean(share, 0)
    assert float(field.max() - field.min()) > 0.2
    # smooth (a sigmoid of 1/f^2.5 noise): neighbours differ by little of the range (independent draws: ~1/3),
    # its steepest transitions included
    jumps = (field[:, 1:] - field[:, :-1]).abs().flatten()
    jumps = jumps[~jumps.isnan()]
    assert float(jumps.median()) < 0.05 and float(jumps.quantile(0.99)) < 0.3


def test_photo_renders_through_the_camera(tmp_path):
    """A photo of a mid-grey (sRGB 128) half and a white half, lifted and rendered by the Camera (diffraction-limited
    optics, Nikon D5100 sensor, no noise): in every channel the raw ratio of the halves is the *linear* ratio 0.216
    (IEC 61966-2-1 decoding of 128/255), not the encoded 0.502; 3 % allows the Airy tails across the edge."""
    from isettorch.camera import Camera
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.sensor import Sensor

    a = np.full((64, 64, 3), 128, np.uint8)
    a[:, 32:] = 255
    Image.fromarray(a).save(tmp_path / "p.png")
    item = PhotoSceneDataset(tmp_path, size=64, seed=0)[0]
    scene = nat.to_scene(item, hfov_deg=1.0)  # 64 scene pixels ~ the 32 x 2 um sensor
    sensor = Sensor(cfa="RGGB", filters="nikon_5100", auto_exposure="luminance", pixel_size_m=2e-6, rows=32, cols=32)
    raw = Camera(DiffractionLimitedOptics(f_number=4.0), sensor, None, noise=False)(
        scene, return_intermediates=True).raw.data[0, 0].double()
    left, right = raw[4:28, 2:12], raw[4:28, 20:30]
    expected = ((128 / 255 + 0.055) / 1.055) ** 2.4
    for dy, dx in ((0, 0), (0, 1), (1, 1)):  # R, G, B sites
        lo, hi = sorted([float(left[dy::2, dx::2].mean()), float(right[dy::2, dx::2].mean())])
        assert lo / hi == pytest.approx(expected, rel=0.03)


def _material_boundary_density(config, n=6, size=64):
    """Fraction of horizontally adjacent pixel pairs whose dominant material differs (colour edges per pixel)."""
    out = []
    for i in range(n):
        k = nat.generate_natural(i, 11, dict(config, size=size))["maps"].argmax(0)
        out.append(float((k[:, 1:] != k[:, :-1]).float().mean()))
    return sum(out) / n


def test_colour_correlation_puts_colour_edges_at_coarse_scales():
    """Natural images change colour at coarse scales and intensity at all scales (their high-frequency colour
    bands are strongly correlated: Gunturk et al., IEEE TIP 2002): with the component on, far fewer neighbouring
    pixels change material than with it off (every leaf and detail item a random material), and fewer the larger
    ``chromatic_radius_px`` and the smaller ``chromatic_detail_probability``."""
    base = {"components": {"illuminant": {"mixed_probability": 0.0}, "depth_layers": {"enabled": False},
                           "grain": {"enabled": False}}}  # the grain layers would win the argmax on dark pixels
    on = _material_boundary_density(base)
    off = _material_boundary_density(nat.natural_config(base, disable=("colour_correlation",)))
    v4 = {"chromatic_radius_px": 16.0, "chromatic_detail_probability": 0.25}  # version 4: colour coarser still
    coarse = _material_boundary_density({"components": {**base["components"], "colour_correlation": v4}})
    assert coarse < 0.5 * off and coarse < on < 0.9 * off, (coarse, on, off)


def test_leaves_smaller_than_the_chromatic_radius_keep_the_material_under_them():
    """chromatic_radius_px: a leaf changes material with probability min(1, r / radius). With an infinite radius
    and no chromatic detail every leaf keeps the background's material (one non-zero map); with a radius below the
    smallest leaf every leaf draws a material, as with the component off."""
    flat = {"size": 48, "components": {"textured_leaves": {"enabled": False}, "fine_detail": {"enabled": False},
                                      "depth_layers": {"enabled": False}, "palette": {"materials": [6, 6]},
                                      "grain": {"enabled": False},
                                      "colour_correlation": {"chromatic_radius_px": 1e9,
                                                             "chromatic_detail_probability": 0.0}}}
    maps = nat.generate_natural(0, 3, flat)["maps"]
    assert int((maps.flatten(1).amax(1) > 0).sum()) == 1
    flat["components"]["colour_correlation"]["chromatic_radius_px"] = 1e-3
    maps = nat.generate_natural(0, 3, flat)["maps"]
    assert int((maps.flatten(1).amax(1) > 0).sum()) >= 5


GRAIN = {"size": 96, "components": {"grain": {"probability": 1.0, "exponent": [0.0, 0.0]},
                                    "illuminant": {"mixed_probability": 0.0}}}


def test_grain_dyes_partition_the_spectrum():
    """The three grain layers (blue, green, red bands) sum to 1 at every wavelength, so equal grain is grey; each
    peaks in its own band; bad edges are named."""
    cfg = nat.natural_config()
    dyes = nat.grain_dyes(cfg, WL)
    assert dyes.shape == (3, WL.numel()) and (dyes >= 0).all()
    assert torch.allclose(dyes.sum(0), torch.ones_like(WL), atol=1e-12)
    assert [float(WL[int(d.argmax())]) for d in dyes] == [400.0, pytest.approx(540.0, abs=20), 700.0]
    with pytest.raises(ValueError, match="dye_edges_nm"):  # the config names it ...
        nat.natural_config({"components": {"grain": {"dye_edges_nm": [600.0, 500.0]}}})
    bad = nat.natural_config()
    bad["components"]["grain"]["dye_edges_nm"] = [600.0, 500.0]
    with pytest.raises(ValueError, match="dye_edges_nm"):  # ... and so does the function, given it unchecked
        nat.grain_dyes(bad, WL)
    with pytest.raises(ValueError, match="amplitude"):
        nat.generate_natural(0, 0, {"size": 32, "components": {"grain": {"probability": 1.0, "amplitude": [0, 0.01]}}})


def test_grain_is_independent_per_layer_with_its_specified_mean():
    """Grain maps: log-normal with mean ``amplitude`` (E[exp(c n - c^2/2)] = 1 for unit Gaussian n), layers
    uncorrelated (independent draws), and the spectrum of white grain flat (slope ~0, exponent 0)."""
    s = nat.generate_natural(2, seed=5, config=GRAIN)
    amp = s["meta"]["grain_amplitude"]
    lo, hi = nat.NATURAL_DEFAULTS["components"]["grain"]["amplitude"]
    assert lo <= amp <= hi
    grain = s["maps"][-3:].double()
    assert torch.allclose(grain.mean((1, 2)), torch.full((3,), amp, dtype=torch.float64), rtol=0.05)
    logs = grain.log().flatten(1)
    assert torch.allclose(logs.std(1), torch.full((3,), 0.7, dtype=torch.float64), rtol=0.05)  # the contrast
    c = torch.corrcoef(logs)
    assert (c - torch.eye(3, dtype=torch.float64)).abs().max() < 0.05
    assert abs(st.power_spectrum_slope(logs[0].reshape(96, 96))) < 0.3
    assert torch.equal(s["spectra"][-3:], nat.grain_dyes(nat.natural_config(GRAIN), WL) * s["illuminant"][None])


def test_grain_draws_last_so_the_other_maps_do_not_change():
    """With grain off the generator draws exactly the scene it draws with grain on, less the three grain layers
    (the version-4 distribution is reachable by config: natural.py's docstring)."""
    on = nat.generate_natural(1, seed=3, config=GRAIN)
    off = nat.generate_natural(1, seed=3, config=nat.natural_config(GRAIN, disable=("grain",)))
    assert on["meta"]["grain_amplitude"] is not None and off["meta"]["grain_amplitude"] is None
    assert torch.equal(on["maps"][:-3], off["maps"]) and torch.equal(on["spectra"][:-3], off["spectra"])


REL = {"size": 96, "components": {"grain": {"probability": 0.0, "exponent": [0.0, 0.0],
                                            "relative": {"probability": 1.0}},
                                  "illuminant": {"mixed_probability": 0.0}}}


def test_relative_grain_multiplies_each_layer_with_its_specified_law():
    """components.grain.relative: the scene drawn without it (every earlier draw is the same) times
    ``sum_k d_k(l) m_k(x)`` exactly (m solved from three wavelengths predicts all 31), with ``m_k`` log-normal of mean
    1 and log-std the drawn contrast, independent between layers; each material becomes three layer maps; off in the
    defaults (version 5); a bad setting raises naming the key."""
    on = nat.generate_natural(4, seed=2, config=REL)
    off_cfg = nat.natural_config(REL)
    off_cfg["components"]["grain"]["relative"]["probability"] = 0.0
    off = nat.generate_natural(4, seed=2, config=off_cfg)
    assert off["meta"]["relative_grain_contrast"] is None and on["maps"].shape[0] == 3 * off["maps"].shape[0]
    c = on["meta"]["relative_grain_contrast"]
    lo, hi = nat.NATURAL_DEFAULTS["components"]["grain"]["relative"]["contrast"]
    assert lo <= c <= hi

    def radiance(s):
        return torch.einsum("jhw,jl->lhw", s["maps"].double(), s["spectra"])

    r_on, r_off = radiance(on), radiance(off)
    assert (r_off > 1e-9 * r_off.max()).all()
    ratio = (r_on / r_off).flatten(1)  # [L, H*W]
    dyes = nat.grain_dyes(nat.natural_config(REL), WL)  # [3, L]
    pick = [0, 14, 30]  # 400, 540, 700 nm
    m = torch.linalg.solve(dyes[:, pick].T, ratio[pick])  # [3, H*W]: the layer fields
    assert torch.allclose(dyes.T @ m, ratio, rtol=1e-4, atol=0)
    assert torch.allclose(m.mean(1), torch.ones(3, dtype=torch.float64), atol=0.03)
    logs = m.log()
    assert torch.allclose(logs.std(1), torch.full((3,), c, dtype=torch.float64), rtol=0.05)
    assert (torch.corrcoef(logs) - torch.eye(3, dtype=torch.float64)).abs().max() < 0.05
    assert nat.NATURAL_DEFAULTS["components"]["grain"]["relative"]["probability"] == 0.0
    assert nat.generate_natural(0, seed=1, config={"size": 32})["meta"]["relative_grain_contrast"] is None
    with pytest.raises(ValueError, match="components.grain.relative"):
        nat.natural_config({"components": {"grain": {"relative": {"contrast": [0.4, 0.1]}}}})


SPEC = {"size": 96, "components": {"specular": {"probability": 1.0}, "illuminant": {"mixed_probability": 0.0}}}


def test_specular_adds_illuminant_coloured_sheen_with_its_specified_law():
    """components.specular (dichromatic interface reflection): the scene drawn without it (every earlier draw is the
    same) plus one map whose spectrum is the illuminant's exactly, so the added radiance is rank one, proportional to
    the light at every pixel (neutral interface reflection); the map divided by the glossy materials' body maps is
    ``a t`` with ``t`` log-normal of mean 1 and log-std the drawn contrast; off in the defaults (version 5); a bad
    setting raises naming the key."""
    glossy_scenes = 0
    for index in range(5):
        on = nat.generate_natural(index, seed=5, config=SPEC)
        off_cfg = nat.natural_config(SPEC)
        off_cfg["components"]["specular"]["probability"] = 0.0
        off = nat.generate_natural(index, seed=5, config=off_cfg)
        sp = on["meta"]["specular"]
        assert off["meta"]["specular"] is None and sp is not None
        assert torch.equal(on["maps"][:-1], off["maps"]) and torch.equal(on["spectra"][:-1], off["spectra"])
        assert torch.equal(on["spectra"][-1], on["illuminant"])
        if not sp["glossy"]:
            assert float(on["maps"][-1].abs().max()) == 0.0
            continue
        added = (torch.einsum("jhw,jl->lhw", on["maps"].double(), on["spectra"])
                 - torch.einsum("jhw,jl->lhw", off["maps"].double(), off["spectra"]))
        shape = added.flatten(1).sum(1)
        assert torch.allclose(added.flatten(1), shape[:, None] / shape.sum() * added.flatten(1).sum(0)[None],
                              rtol=1e-6, atol=1e-12 * float(added.abs().max()))
        c = nat.NATURAL_DEFAULTS["components"]["specular"]
        assert c["amplitude"][0] <= sp["amplitude"] <= c["amplitude"][1]
        assert c["contrast"][0] <= sp["contrast"] <= c["contrast"][1]
        n_mat = len(on["meta"]["materials"])
        body = off["maps"][:n_mat][sp["glossy"]].sum(0).double()
        keep = body > 1e-6 * body.max()
        t = on["maps"][-1].double()[keep] / body[keep] / sp["amplitude"]
        assert abs(float(t.mean()) - 1.0) < 0.1
        assert abs(float(t.log().std()) - sp["contrast"]) < 0.1 * sp["contrast"] + 0.02
        glossy_scenes += 1
    assert glossy_scenes >= 3
    assert nat.NATURAL_DEFAULTS["components"]["specular"]["probability"] == 0.0
    assert nat.generate_natural(0, seed=1, config={"size": 32})["meta"]["specular"] is None
    for bad in ({"glossy_fraction": 0.0}, {"contrast": [0.5, 0.1]}, {"amplitude": [0.0, 0.1]}):
        with pytest.raises(ValueError, match="components.specular"):
            nat.natural_config({"components": {"specular": bad}})


def test_training_configs_name_valid_generator_settings():
    """Every configs/train demosaic config's data.natural is a valid override (a misspelt key would raise only
    after minutes of bank rendering), and the version-4 pin of the first noise-free stage differs from the
    defaults exactly where natural.py's docstring says."""
    from pathlib import Path

    import yaml

    root = Path(__file__).resolve().parents[2] / "configs" / "train"
    configs = {p.name: yaml.safe_load(p.read_text()) for p in sorted(root.glob("demosaic*.yaml"))}
    assert "demosaic_noise_free_finetune.yaml" in configs
    for cfg in configs.values():
        nat.natural_config((cfg.get("data") or {}).get("natural") or {})  # raises naming the key
    v4 = nat.natural_config(configs["demosaic_noise_free.yaml"]["data"]["natural"])["components"]
    v5 = nat.NATURAL_DEFAULTS["components"]
    changed = {(c, k) for c in v5 for k in v5[c] if v4[c][k] != v5[c][k]}
    assert changed == {("colour_correlation", "chromatic_radius_px"),
                       ("colour_correlation", "chromatic_detail_probability"), ("grain", "enabled")}
    assert configs["demosaic_joint_denoise.yaml"]["data"]["natural"] == configs["demosaic_noise_free.yaml"]["data"][
        "natural"]  # the joint run shares the first stage's scene bank


def test_dye_component_draws_its_specified_probability_and_concentration_law():
    """components.palette.dye: a non-grey material is dyed with ``probability`` at a log-uniform concentration in
    ``concentration`` (binomial and Kolmogorov-Smirnov checks), greys never; off (the default, version 5) every
    material is undyed; a bad setting raises naming the key."""
    from scipy import stats

    cfg = nat.natural_config({"components": {"palette": {"dye": {"probability": 0.4, "concentration": [1.0, 4.0]}}}})
    wl = nat._wavelengths(cfg)
    conc, grey_dyed, n_plain = [], 0, 0
    for i in range(400):
        _, kinds, c = nat._palette(cfg, wl, torch.Generator().manual_seed(i))
        for k, ci in zip(kinds, c):
            if k == "grey":
                grey_dyed += ci != 1.0
            else:
                n_plain += 1
                conc.append(ci)
    dyed = np.array([c for c in conc if c != 1.0])
    assert grey_dyed == 0 and stats.binomtest(len(dyed), n_plain, 0.4).pvalue > 1e-3
    assert stats.kstest(np.log(dyed) / math.log(4.0), "uniform").pvalue > 1e-3
    assert dyed.min() >= 1.0 and dyed.max() <= 4.0
    off = nat.generate_natural(2, seed=5, config=SMALL)
    assert off["meta"]["dye_concentrations"] == [1.0] * len(off["meta"]["materials"])
    with pytest.raises(ValueError, match="components.palette.dye"):
        nat.generate_natural(0, seed=0, config={"components": {"palette": {"dye": {"probability": 1.5}}}})
    with pytest.raises(ValueError, match="components.palette.dye"):
        nat.generate_natural(0, seed=0, config={"components": {"palette": {"dye": {"concentration": 2.0}}}})


def test_a_grating_beyond_nyquist_is_refused():
    """Sampled at pixel centres, a grating of 1 or 2 cycles/pixel was a flat field and 0.75 came out as 0.25."""
    g = torch.Generator().manual_seed(0)
    assert float(tex.warped_grating(16, 16, 0.5, 0.0, 0.0, g).std()) > 0.3  # Nyquist: still a grating
    for f in (0.75, 1.0, 2.0):
        with pytest.raises(ValueError, match=r"frequency_cpp: expected \(0, 0.5\] cycles/pixel"):
            tex.warped_grating(16, 16, f, 0.0, 0.0, g)


def test_items_do_not_depend_on_torch_default_dtype():
    """A scene depends on (seed, index, config) alone. Probability draws were made in torch's default dtype, so with
    set_default_dtype(float64) the generator's stream shifted: 8 of 8 natural items became other scenes (8
    materials -> 16 spectra, a second light), 1 of 8 layout scenes (the shadow disk's draw) and the photo crops'
    flips. Every such draw is now float32, the stream under the default default."""
    from isettorch.data.scenes import generate_scene

    def snap():
        items = [nat.generate_natural(i, 3, {"size": 32}) for i in range(4)]
        lay = [generate_scene(i, 3, {"height": 32, "width": 32}, dtype=torch.float64) for i in range(8)]
        return items, lay

    a = snap()
    old = torch.get_default_dtype()
    try:
        torch.set_default_dtype(torch.float64)
        b = snap()
    finally:
        torch.set_default_dtype(old)
    for x, y in zip(a[0], b[0]):
        assert x["meta"] == y["meta"]
        torch.testing.assert_close(x["maps"].double(), y["maps"].double(), rtol=0, atol=1e-6)
    for x, y in zip(a[1], b[1]):  # (float32 rounding of a CCT, documented, moves them by < 1e-7)
        torch.testing.assert_close(x.photons, y.photons, rtol=1e-6, atol=0)
