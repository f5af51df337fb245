"""PairStream with the natural generator: :func:`isettorch.data.batched_natural.draw_natural_scenes` against the
per-item generator (:func:`isettorch.data.natural.generate_natural` as CameraPairDataset crops and scales it).

Distribution tests compare per-item summary statistics by a two-sample z test (means within 4 combined standard
errors; both samples are fixed by their seeds, so a test passes or fails deterministically), proportions against
the configured probabilities within 4 binomial standard errors, and the leaf-size law by Kolmogorov-Smirnov
against its closed-form CDF.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from isettorch import spectral
from isettorch.data import PairStream, natural
from isettorch.data.batched_natural import draw_natural_scenes
from isettorch.data.camera_pairs import _natural_scene
from isettorch.data.config import SCENE_DEFAULTS, merge_config, one_thread
from isettorch.data.scenes import _luminance_weights
from isettorch.image import XYZ_TO_LINEAR_SRGB
from isettorch.metrics.image_statistics import cross_channel_gradient_correlation, power_spectrum_slope

SIZE = 32
NAT = {"generator": "natural", "height": SIZE, "width": SIZE}


@pytest.fixture(autouse=True)
def _one_thread():
    """One intra-op thread: the leaf painter's many small ops cost most in thread hand-offs on a shared CPU."""
    with one_thread():
        yield


def _z_close(a, b, n_sigma=4.0):
    a, b = np.asarray(a, float), np.asarray(b, float)
    se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    return abs(a.mean() - b.mean()) <= n_sigma * se, (a.mean(), b.mean(), se)


def _proportion_ok(flags, p, n_sigma=4.0):
    flags = np.asarray(flags, float)
    return abs(flags.mean() - p) <= n_sigma * math.sqrt(p * (1 - p) / flags.size), (flags.mean(), p)


def _stats(maps, spectra, wl):
    """Per item: log mean luminance, mean chromaticity x, y, mean |gradient| of log luminance, the correlation of
    the R and G first differences in linear sRGB (Gunturk et al. 2002's high-pass correlation) and the luminance
    power-spectrum slope (isettorch.metrics.image_statistics)."""
    wl = wl.to(torch.float64)
    maps, spectra = maps.to(torch.float64), spectra.to(torch.float64)
    v = _luminance_weights(wl)
    cmf = spectral.cmfs(wl, dtype=torch.float64).T  # [L, 3]
    y_img = torch.einsum("bj,bjhw->bhw", spectra @ v, maps)
    xyz_img = torch.einsum("bjc,bjhw->bchw", spectra @ cmf, maps)
    xyz = xyz_img.mean((-2, -1))
    xy = xyz[:, :2] / xyz.sum(1, keepdim=True)
    rgb = torch.einsum("ij,bjhw->bihw", torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64), xyz_img)
    logy = torch.log(y_img.clamp_min(1e-9))
    grad = (logy[:, 1:, :] - logy[:, :-1, :]).abs().mean((1, 2)) + (logy[:, :, 1:] - logy[:, :, :-1]).abs().mean((1, 2))
    rg = torch.tensor([cross_channel_gradient_correlation(c, 0, 1) for c in rgb], dtype=torch.float64)
    slope = torch.tensor([power_spectrum_slope(y) for y in y_img], dtype=torch.float64)
    return {"log_lum": torch.log(y_img.mean((1, 2))), "x": xy[:, 0], "y": xy[:, 1], "grad": grad, "rg_corr": rg,
            "slope": slope}


def _batched(n, seed, scene=None, batch=32, size=SIZE):
    cfg = merge_config(dict(NAT, **(scene or {})), SCENE_DEFAULTS, "scene")
    g = torch.Generator().manual_seed(seed)
    return [draw_natural_scenes(batch, g, cfg, size=(size, size), device="cpu", dtype=torch.float64)
            for _ in range(n // batch)]


def test_scene_distribution_matches_generate_natural(monkeypatch):
    n = 64
    parts = _batched(n, 3)
    wl = parts[0]["wavelengths_nm"]
    got: dict = {}
    for p in parts:
        for key, v in _stats(p["maps"], p["spectra"], wl).items():
            got.setdefault(key, []).append(v)
        for key in ("mixed_light", "foreground", "grain", "materials"):
            got.setdefault(key, []).append(p["meta"][key].to(torch.float64))
        got.setdefault("fine_detail", []).append((p["meta"]["fine_detail_items"] > 0).to(torch.float64))
        got.setdefault("fg_coverage", []).append(p["meta"]["foreground_coverage"])
    got = {k: torch.cat(v).numpy() for k, v in got.items()}
    # the per-item path (CameraPairDataset's _natural_scene); the foreground layer's coverage read by a spy on the
    # painter (it does not change the draws)
    coverage = []
    painter = natural._paint_leaves

    def spy(cfg, g, maps, n_leaves, r_min, r_max, exponent, alpha=None):
        out = painter(cfg, g, maps, n_leaves, r_min, r_max, exponent, alpha=alpha)
        if alpha is not None:
            coverage.append(float(alpha.to(torch.float64).mean()))
        return out

    monkeypatch.setattr(natural, "_paint_leaves", spy)
    cfg = merge_config(NAT, SCENE_DEFAULTS, "scene")
    ref: dict = {}
    for i in range(n):
        before = len(coverage)
        s = _natural_scene(i, 7, cfg, (SIZE, SIZE), 10.0, 1.2, torch.float64)
        for key, v in _stats(s.factors.maps, s.factors.spectra, wl).items():
            ref.setdefault(key, []).append(float(v[0]))
        m = s.metadata
        ref.setdefault("mixed_light", []).append(float(len(m["illuminants"]) == 2))
        ref.setdefault("foreground", []).append(float(m["defocus_diopters"] is not None))
        ref.setdefault("grain", []).append(float(m["grain_amplitude"] is not None))
        ref.setdefault("materials", []).append(float(len(m["materials"])))
        ref.setdefault("fine_detail", []).append(float(len(m["fine_detail"]) > 0))
        ref.setdefault("fg_coverage", []).append(coverage[-1] if len(coverage) > before else 0.0)
    for key in got:
        ok, info = _z_close(got[key], ref[key])
        assert ok, (key, info)
    # the configured probabilities (NATURAL_DEFAULTS)
    comp = natural.NATURAL_DEFAULTS["components"]
    for key, p in (("mixed_light", comp["illuminant"]["mixed_probability"]),
                   ("foreground", comp["depth_layers"]["probability"]), ("grain", comp["grain"]["probability"]),
                   ("fine_detail", comp["fine_detail"]["probability"])):
        for sample in (got[key], ref[key]):
            ok, info = _proportion_ok(sample, p)
            assert ok, (key, info)


def test_component_probabilities():
    """Each component is drawn with its configured probability (NATURAL_DEFAULTS): exact binomial tests on 400
    items (a probability off by 0.1 gives p < 1e-4; the 16- and 64-item checks above cannot tell)."""
    from scipy.stats import binomtest

    parts = _batched(400, 11, batch=100, size=16)
    comp = natural.NATURAL_DEFAULTS["components"]
    for key, p in (("mixed_light", comp["illuminant"]["mixed_probability"]),
                   ("foreground", comp["depth_layers"]["probability"]), ("grain", comp["grain"]["probability"]),
                   ("fine_detail", comp["fine_detail"]["probability"])):
        flags = torch.cat([q["meta"]["fine_detail_items"] > 0 if key == "fine_detail" else q["meta"][key].bool()
                           for q in parts])
        assert binomtest(int(flags.sum()), flags.numel(), p).pvalue > 1e-3, (key, float(flags.double().mean()), p)


def test_leaf_size_law():
    """Background leaf radii follow p(r) ~ r^-3 on [0.8, 0.5 n] (Lee, Mumford & Huang 2001): KS test against the
    closed-form CDF F(r) = (rmin^-2 - r^-2) / (rmin^-2 - rmax^-2); counts in the configured [500, 1200]."""
    from scipy import stats

    (out,) = _batched(4, 2, batch=4, size=48)
    r, count = out["meta"]["leaf_radius"], out["meta"]["leaf_count"]
    assert bool(((count >= 500) & (count <= 1200)).all())
    radii = torch.cat([r[b, :int(count[b])] for b in range(4)]).numpy()
    assert bool((r[:, 1:] <= r[:, :-1]).all()), "painted large to small"
    rmin, rmax = 0.8, 0.5 * 48

    def cdf(x):
        return (rmin**-2 - np.clip(x, rmin, rmax) ** -2) / (rmin**-2 - rmax**-2)

    assert stats.kstest(radii, cdf).pvalue > 1e-3


def test_stream_repeatable_and_equal_to_camera_calls(stream_equals_camera):
    stream = PairStream(4, seed=2, scene=NAT, camera={"pixel_size_m": [1.4e-6, 2.8e-6]})
    batch = stream.batch(1)
    again = PairStream(4, seed=2, scene=NAT, camera={"pixel_size_m": [1.4e-6, 2.8e-6]}).batch(1)
    for key in ("raw", "noise_free_raw", "camera_rgb", "linear_srgb"):
        assert torch.equal(batch[key], again[key]), key
    assert not torch.equal(stream.batch(2)["raw"], batch["raw"])
    assert float(batch["meta"]["hdr_decades"].abs().max()) == 0.0
    stream_equals_camera(stream, 1, PairStream(3, seed=4, scene=NAT, camera={"pixel_size_m": [2.0e-6]},
                                               targets=("camera_rgb",)), 5)


def _grey_fraction(out):
    """Fraction of the drawn materials (under light 1) whose reflectance is flat (a grey)."""
    refl = out["spectra"] / out["white"][:, None]
    flat = (refl.amax(-1) - refl.amin(-1)) <= 1e-9 * refl.amax(-1)
    k = out["meta"]["materials"]
    return torch.cat([flat[b, :int(k[b])] for b in range(flat.shape[0])]).to(torch.float64).numpy()


def _flat_fraction(out):
    """Per item: fraction of horizontal neighbours whose log luminance differs by less than 1e-6 (flat areas)."""
    wl = out["wavelengths_nm"]
    y = torch.einsum("bj,bjhw->bhw", out["spectra"] @ _luminance_weights(wl), out["maps"])
    d = (torch.log(y[:, :, 1:]) - torch.log(y[:, :, :-1])).abs()
    return (d < 1e-6).to(torch.float64).mean((1, 2)).numpy()


def _chroma_edge_ratio(out):
    """Per item: neighbours whose chromaticity (log X/Y or log Z/Y) changes by more than 0.02, relative to those
    whose log luminance does: colour edges per intensity edge (low when fine detail is achromatic)."""
    wl = out["wavelengths_nm"]
    cmf = spectral.cmfs(wl, dtype=torch.float64).T
    xyz = torch.einsum("bjc,bjhw->bchw", out["spectra"] @ cmf, out["maps"]).clamp_min(1e-12)
    c = torch.stack([torch.log(xyz[:, 0] / xyz[:, 1]), torch.log(xyz[:, 2] / xyz[:, 1])], 1)
    y = torch.log(xyz[:, 1])
    dc = (c[..., 1:] - c[..., :-1]).abs().amax(1)
    dy = (y[..., 1:] - y[..., :-1]).abs()
    return ((dc > 0.02).to(torch.float64).mean((1, 2)) / (dy > 0.02).to(torch.float64).mean((1, 2)).clamp_min(1e-3)
            ).numpy()


# one component off at a time; plain scenes (no shading, grain, detail, layers, second light; few larger leaves)
# isolate the leaves and their textures
_PLAIN = {"components": {"colour_correlation": {"contrast": [0.0, 0.0]}, "grain": {"enabled": False},
                         "fine_detail": {"enabled": False}, "depth_layers": {"enabled": False},
                         "illuminant": {"mixed_probability": 0.0}}}
_BASES = {"textured_leaves": {"components": dict(_PLAIN["components"], dead_leaves={"leaves": [30, 30],
                                                                                      "r_min_px": 4.0})},
          "dead_leaves": {"components": dict(_PLAIN["components"], textured_leaves={"enabled": False})},
          "colour_correlation": {"components": {"grain": {"enabled": False}}},
          "specular": {"components": {"specular": {"probability": 1.0}}}}


def _off(name, base=None):
    cfg = {"components": dict((base or {}).get("components", {}))}
    cfg["components"][name] = dict(cfg["components"].get(name, {}), enabled=False)
    return cfg


@pytest.mark.parametrize("name", ["palette", "illuminant", "dead_leaves", "textured_leaves", "colour_correlation",
                                  "depth_layers", "fine_detail", "grain", "specular"])
def test_component_switch_changes_its_statistic(name):
    n = 32 if name == "colour_correlation" else 16
    base = _BASES.get(name, {})
    (on,) = _batched(n, 5, {"natural": base}, batch=n)
    (off,) = _batched(n, 5, {"natural": _off(name, base)}, batch=n)
    if name == "palette":  # greys with grey_probability; off: smooth random spectra only
        assert _proportion_ok(_grey_fraction(on), 0.15)[0] and _grey_fraction(off).sum() == 0
    elif name == "illuminant":  # off: daylight at 6500 K only, no second light
        assert float(on["meta"]["cct_k"].std()) > 100 and bool(on["meta"]["mixed_light"].any())
        torch.testing.assert_close(off["meta"]["cct_k"], torch.full((n,), 6500.0, dtype=torch.float64))
        assert not bool(off["meta"]["mixed_light"].any())
    elif name == "dead_leaves":  # off: 12 leaves of radius n / 4, so large flat areas
        assert bool((on["meta"]["leaf_count"] >= 500).all())
        assert bool((off["meta"]["leaf_count"] == 12).all())
        torch.testing.assert_close(off["meta"]["leaf_radius"][:, :12], torch.full((n, 12), SIZE / 4,
                                                                                  dtype=torch.float64), rtol=1e-6,
                                   atol=0)
        a, b = _flat_fraction(on), _flat_fraction(off)
        assert b.mean() > a.mean() and not _z_close(a, b)[0], (a.mean(), b.mean())
    elif name == "textured_leaves":  # off: flat leaf interiors (no shading field here)
        a, b = _flat_fraction(on), _flat_fraction(off)
        assert b.mean() > a.mean() and not _z_close(a, b)[0], (a.mean(), b.mean())
    elif name == "colour_correlation":  # off: fine detail that changes colour: more colour edges per intensity edge
        a, b = _chroma_edge_ratio(on), _chroma_edge_ratio(off)
        assert b.mean() > a.mean() and not _z_close(a, b, 3.0)[0], (a.mean(), b.mean())
    elif name == "depth_layers":
        assert bool(on["meta"]["foreground"].any())  # its probability: test_component_probabilities
        assert float(on["meta"]["foreground_coverage"].max()) > 0
        assert not bool(off["meta"]["foreground"].any()) and float(off["meta"]["foreground_coverage"].abs().max()) == 0
    elif name == "fine_detail":
        assert bool((on["meta"]["fine_detail_items"] > 0).any())
        assert int(off["meta"]["fine_detail_items"].max()) == 0
    elif name == "grain":  # three grain maps with the dye bands' spectra, used by the items that draw grain
        assert bool(on["meta"]["grain"].any()) and not bool(off["meta"]["grain"].any())
        assert on["maps"].shape[1] > off["maps"].shape[1]
    else:  # specular with probability 1: a sheen map (the illuminant's spectrum) on every item
        assert bool(on["meta"]["specular"].all()) and not bool(off["meta"]["specular"].any())
        k = on["spectra"].shape[1] // (2 if bool(on["meta"]["mixed_light"].any()) else 1) - 1
        torch.testing.assert_close(on["spectra"][:, k], on["white"])
        assert bool(on["used"][:, k].any())


def test_relative_grain_and_dye_options():
    """``grain.relative`` (probability 1): each material's map is split into the three emulsion layers, whose
    spectra ``r d_k`` sum to the material's ``r`` (the dye bands sum to 1); ``palette.dye`` (probability 1,
    concentration 3): a non-grey material's reflectance is its undyed one raised to the power 3 at the same peak
    (Beer-Lambert), so the ratio of its minimum to its peak is cubed."""
    from isettorch.data.natural import grain_dyes

    rel = {"components": {"grain": {"probability": 1.0, "relative": {"probability": 1.0}}}}
    (out,) = _batched(8, 6, {"natural": rel}, batch=8)
    assert bool(out["meta"]["relative_grain"].all())
    kmax = 8
    refl = out["spectra"] / out["white"][:, None]
    layers = refl[:, :3 * kmax].reshape(8, kmax, 3, -1)
    dyes = grain_dyes(natural.natural_config(), out["wavelengths_nm"])
    torch.testing.assert_close(layers / layers.sum(2, keepdim=True).clamp_min(1e-300), dyes[None, None].expand_as(
        layers) * (layers.sum(2, keepdim=True) > 0), rtol=1e-9, atol=1e-12)
    flat = {"components": {"palette": {"grey_probability": 0.0}}}
    dyed = {"components": {"palette": {"grey_probability": 0.0, "dye": {"probability": 1.0,
                                                                       "concentration": [3.0, 3.0]}}}}
    (a,) = _batched(16, 8, {"natural": flat}, batch=16)
    (b,) = _batched(16, 8, {"natural": dyed}, batch=16)

    def purity(out):
        r = out["spectra"] / out["white"][:, None]
        k = out["meta"]["materials"]
        ratio = r.amin(-1) / r.amax(-1)
        return torch.cat([ratio[i, :int(k[i])] for i in range(ratio.shape[0])]).numpy()

    # the same generator state draws the same undyed materials (the dye draws come after them): min / peak is
    # raised to the concentration, (r_min / r_peak)^3
    np.testing.assert_allclose(purity(b), purity(a) ** 3, rtol=1e-9, atol=1e-15)


def test_bad_input_names_the_argument():
    cfg = merge_config(NAT, SCENE_DEFAULTS, "scene")
    g = torch.Generator().manual_seed(0)
    with pytest.raises(ValueError, match="nb"):
        draw_natural_scenes(0, g, cfg, size=(16, 16), device="cpu")
    with pytest.raises(ValueError, match="size"):
        draw_natural_scenes(2, g, cfg, size=(0, 16), device="cpu")
    with pytest.raises(ValueError, match="scene.natural"):
        PairStream(2, scene=dict(NAT, natural={"components": {"grain": {"amplitud": 0.01}}}))
