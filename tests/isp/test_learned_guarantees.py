"""The guarantees the shipped learned demosaickers carry (isettorch.isp.learned.guard_residual, issue #35): exact on
constant colour fields, no colour bias of their own, the documented behaviour under brightness scaling, and never
more than 0.1 dB below Malvar-He-Cutler (MHC) on the stress set (training/stress_set.py; never Kodak/McMaster)."""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from isettorch.isp import learned
from isettorch.isp.demosaicing import demosaic, demosaic_malvar2004, mosaic

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from training import stress_set as ss  # noqa: E402

pytestmark = pytest.mark.skipif(not all(p.is_file() for p in learned.PRETRAINED.values()),
                                reason="no shipped checkpoints")
PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")
# stress images on which the floor is known not to hold (the ambiguity of the Bayer mosaic: a green-magenta
# pattern has the mosaic of a fine diagonal grey texture, which the network prefers); see the model card
KNOWN_BELOW_MHC = ("pattern:star/green_magenta", "pattern:zone_plate/green_magenta")


def _colours():
    g = torch.Generator().manual_seed(35)
    fixed = [(0.5, 0.5, 0.5), (0.02, 0.02, 0.02), (0.9, 0.2, 0.1), (0.1, 0.6, 0.9), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0),
             (1e-4, 3e-4, 2e-4), (0.99, 0.0, 0.5), (3.0, 2.0, 1.0)]
    return [torch.tensor(c) for c in fixed] + [torch.rand(3, generator=g) * 10 ** -float(k) for k in range(4)]


@pytest.mark.parametrize("variant", sorted(learned.PRETRAINED))
def test_constant_colour_fields_are_exact(variant):
    # Any level (1e-4 ... 3, above white too) and colour, every Bayer phase, borders included: the value itself.
    net = learned.load_pretrained(variant)
    noise = learned.noise_features(1e-3, 1e-4).float() if net.noise_inputs else None
    colours = torch.stack(_colours()).float()
    fields = colours[:, :, None, None].expand(-1, 3, 32, 40).contiguous()  # one field per batch item
    full_scale = colours.amax(1).clamp_min(1.0)[:, None, None, None]
    if noise is not None:
        noise = noise.expand(len(colours), -1)
    for pattern in PATTERNS:
        out = learned.demosaic_learned(mosaic(fields, pattern), pattern, model=net, noise=noise)
        worst = float(((out - fields).abs() / full_scale).max())
        assert worst <= 1e-5, (pattern, worst)
    # and through the registry, the entry point users call (every method a shipped noise-free network registers)
    field = torch.tensor([0.7, 0.3, 0.05]).view(1, 3, 1, 1).expand(2, 3, 24, 24).contiguous()
    for method in learned.LEARNED_METHODS:
        out = demosaic(mosaic(field, "GBRG"), "GBRG", method=method)
        torch.testing.assert_close(out, field, rtol=0, atol=1e-5)
    # odd heights and widths too (the cells completed by reflection), every phase
    odd = torch.tensor([0.9, 0.2, 0.1]).view(1, 3, 1, 1).expand(1, 3, 21, 19).contiguous()
    for method in learned.LEARNED_METHODS:
        for pattern in PATTERNS:
            torch.testing.assert_close(demosaic(mosaic(odd, pattern), pattern, method=method), odd, rtol=0, atol=1e-5)


def test_constant_fields_stay_exact_with_bfloat16_convolutions():
    # under autocast only the networks' convolutions run in bfloat16 (DemosaicNet keeps its base, blend and guard in
    # the input's precision), so the gate still zeroes the correction on a constant field: exact, not 2^-9
    field = torch.tensor([0.8, 0.35, 0.05]).view(1, 3, 1, 1).expand(1, 3, 20, 18).contiguous()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        for method in learned.LEARNED_METHODS:
            out = demosaic(mosaic(field, "BGGR"), "BGGR", method=method)
            assert out.dtype == torch.float32
            torch.testing.assert_close(out, field, rtol=0, atol=1e-5)


def test_odd_sizes_change_only_the_pixels_near_the_added_row_and_column():
    # An odd-sized mosaic is the even one cut by a row and a column; away from the cut (beyond the network's
    # receptive field and the guard's high-pass, about 100 px) the output is the even image's, to float rounding
    g = torch.Generator().manual_seed(7)
    img = torch.nn.functional.avg_pool2d(torch.rand(1, 3, 200, 200, generator=g), 3, 1, 1)
    whole = learned.demosaic_learned(mosaic(img, "GRBG"), "GRBG")
    cut = learned.demosaic_learned(mosaic(img[..., :199, :197], "GRBG"), "GRBG")
    assert cut.shape[-2:] == (199, 197)
    torch.testing.assert_close(cut[..., :90, :90], whole[..., :90, :90], rtol=0, atol=1e-6)


def test_unguarded_network_is_not_exact_on_constant_fields():
    # the guard is what makes the guarantee: the bare shipped network misses a coloured field by > 1e-3
    field = torch.tensor([0.9, 0.2, 0.1]).view(1, 3, 1, 1).expand(1, 3, 48, 48).contiguous()
    out = learned.demosaic_learned(mosaic(field, "RGGB"), model=learned.load_pretrained(guard=False))
    assert float((out - field)[..., 8:-8, 8:-8].abs().max()) > 1e-3


def test_structure_gate_is_its_documented_formula_by_scipy():
    """The gate recomputed in NumPy with SciPy's box filter (``uniform_filter``, ``nearest`` border = replicate) from
    its docstring: the four Bayer planes' mean of |d2/dx2| + |d2/dy2| (edge rows/columns repeating their
    neighbour's) boxed over the window, against the largest plane's boxed level, ``s^p / (s^p + (rel L)^p + abs^p)``
    per 2 x 2 cell."""
    from scipy.ndimage import uniform_filter

    rng = np.random.default_rng(4)
    raw = rng.random((40, 52)) ** 3 * np.linspace(0.2, 1.0, 52)  # texture, a ramp and dark corners
    planes = [raw[dy::2, dx::2] for dy in (0, 1) for dx in (0, 1)]

    def d2(p, axis):
        d = np.abs(np.diff(p, 2, axis=axis))
        return np.pad(d, [(1, 1) if a == axis else (0, 0) for a in range(2)], mode="edge")

    for rel, ab, window, power in ((0.1, 0.03, 5, 4), (0.2, 0.01, 3, 2.5)):
        curv = np.mean([d2(p, 1) + d2(p, 0) for p in planes], 0)
        s = uniform_filter(curv, window, mode="nearest")
        level = np.max([uniform_filter(p, window, mode="nearest") for p in planes], 0)
        want = s**power / (s**power + (rel * level) ** power + ab**power)
        got = learned.structure_gate(torch.from_numpy(raw)[None, None], rel=rel, abs=ab, window=window, power=power)
        np.testing.assert_allclose(got[0, 0].numpy(), np.kron(want, np.ones((2, 2))), rtol=1e-9, atol=1e-12)


def test_structure_gate_zero_on_constants_one_on_texture_and_scale_covariant():
    g = torch.Generator().manual_seed(0)
    const = mosaic(torch.tensor([0.3, 0.8, 0.1]).view(1, 3, 1, 1).expand(1, 3, 16, 16).contiguous())
    assert float(learned.structure_gate(const).abs().max()) == 0.0
    texture = torch.rand(1, 1, 32, 32, generator=g, dtype=torch.float64)
    assert float(learned.structure_gate(texture).min()) > 0.99
    # s and the level scale with the mosaic, so scaling abs with it leaves the gate unchanged
    ramp = torch.linspace(0, 1, 32, dtype=torch.float64).view(1, 1, 1, 32) ** 2 * (1 + 0.3 * texture)
    a = learned.structure_gate(ramp, rel=0.1, abs=0.02)
    b = learned.structure_gate(ramp * 0.01, rel=0.1, abs=0.02 * 0.01)
    torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="abs"):
        learned.structure_gate(texture, abs=0.0)
    with pytest.raises(ValueError, match="window"):
        learned.structure_gate(texture, window=4)
    with pytest.raises(ValueError, match="guard"):
        learned.DemosaicNet(channels=4, depth=1, guard={"relative": 0.1})


def test_structure_gate_is_finite_far_above_white():
    """The gate's powers are taken of ratios to the largest term: s^4 and (rel L)^4 overflowed to inf / inf = NaN
    from ~1e9 x white in float32, and the whole image came out NaN. A bright mosaic is textured for the gate (1)."""
    g = torch.Generator().manual_seed(1)
    texture = torch.rand(1, 1, 32, 32, generator=g)
    for scale in (1e10, 1e30):
        gate = learned.structure_gate(texture * scale)
        assert bool(torch.isfinite(gate).all()) and float(gate.min()) > 0.99
        out = demosaic(texture * scale, "RGGB", "learned_tiny")
        assert bool(torch.isfinite(out).all())
    assert float(learned.structure_gate(torch.zeros(1, 1, 8, 8)).abs().max()) == 0.0  # 0 / 0 never taken


def test_pretrained_copies_and_inputs_the_networks_refuse():
    """load_pretrained gives each caller its own network: changing its scale, weights or dtype changes neither a
    later load nor the registered methods. Half-precision mosaics, NaN or negative noise features and unknown
    options are refused by name; an empty batch gives an empty image."""
    raw = torch.rand(1, 1, 16, 16, generator=torch.Generator().manual_seed(2))
    before = demosaic(raw, "RGGB", "learned")
    net = learned.load_pretrained()
    scale = net.correction_scale
    net.correction_scale, net.guard = 0.0, None
    with torch.no_grad():
        net.head.weight.mul_(3)
    net.double()
    assert learned.load_pretrained() is not net and learned.load_pretrained().correction_scale == scale
    torch.testing.assert_close(demosaic(raw, "RGGB", "learned"), before, rtol=0, atol=0)
    for dtype in (torch.float16, torch.bfloat16):
        for method in ("learned", "learned_tiny", "menon2007", "malvar2004"):
            with pytest.raises(TypeError, match="raw: expected .*float32 or float64"):
                demosaic(raw.to(dtype), "RGGB", method)
    with pytest.raises(TypeError, match=r"method 'learned': unknown option\(s\) \['variant'\]"):
        demosaic(raw, "RGGB", "learned", variant="tiny")
    with pytest.raises(TypeError, match="refine: expected True or False"):
        demosaic(raw, "RGGB", "menon2007", refine="no")
    for noise, message in ((torch.tensor([[float("nan"), 0.0]]), "noise: expected finite"),
                           (torch.tensor([[-1.0, -1.0]]), "noise: expected non-negative")):
        with pytest.raises(ValueError, match=message):
            learned.demosaic_learned(raw, "RGGB", variant="joint_denoise", noise=noise)
    assert demosaic(torch.zeros(0, 1, 8, 8), "RGGB", "learned").shape == (0, 3, 8, 8)


def _phase_mean_error(net, img: torch.Tensor, crop: int = 10) -> torch.Tensor:
    """Per-image, per-channel mean error (B, 3) in 1/255 over the four Bayer phases: each channel is then sampled
    once at every pixel, so the sampling luck of one phase cancels and what is left is the method's own bias.
    ``img``: (B, 3, H, W)."""
    errs = []
    for pattern in PATTERNS:
        with torch.no_grad():
            out = learned.demosaic_learned(mosaic(img, pattern).float(), pattern, model=net)
        errs.append((out.double() - img)[..., crop:-crop, crop:-crop].mean((2, 3)))
    return torch.stack(errs).mean(0) * 255


@pytest.mark.parametrize("variant", sorted(set(learned.LEARNED_METHODS.values())))
def test_no_channel_bias_on_natural_images(variant):
    # scikit-image's photographs (256 px centre crops) and two generator scenes (not Kodak/McMaster), for every
    # shipped noise-free network (the speed-error family)
    photos = torch.stack([ss.photo(p, 256) for p in ("astronaut.png", "coffee.png", "chelsea.png",
                                                     "hubble_deep_field.jpg")])
    scenes = torch.stack([x for _, x in ss.natural_scenes(2, 128)])
    net = learned.load_pretrained(variant)
    for batch in (photos, scenes):
        bias = _phase_mean_error(net, batch)
        assert float(bias.abs().max()) <= 0.05, bias.tolist()


def test_brightness_scaling():
    # Documented behaviour: the network is not scale-equivariant (trained at white = 1), the guard is relative to
    # the local level above ~abs / rel = 0.3 of white and absolute below, so (a) a dark mosaic falls back to MHC,
    # which is linear: out(k x) / k -> MHC(x) as k -> 0; (b) at every scaling the floor against MHC holds.
    img = ss.photo("coffee.png", 96)[None]
    raw = mosaic(img).float()
    mhc = demosaic_malvar2004(raw, boundary="mirror")
    k = 1e-3
    dark = learned.demosaic_learned(raw * k) / k
    assert float((dark - mhc).abs().max()) <= 1e-4
    from isettorch.isp.evaluation import cpsnr

    for k in (1.0, 0.3, 0.1, 0.03):
        truth = img * k
        ours = cpsnr(learned.demosaic_learned(raw * k).double().clamp(0, 1), truth, 10)
        base = cpsnr(demosaic_malvar2004(raw * k, boundary="mirror").double().clamp(0, 1), truth, 10)
        assert float(ours) >= float(base) - 0.1, (k, float(ours), float(base))


@pytest.mark.parametrize("method", sorted(learned.LEARNED_METHODS))
def test_above_white_the_correction_fades_to_the_reference(method):
    """The networks were trained at white = 1 and are not scale-equivariant: on a photograph x 2, ``learned`` was
    below MHC (-3.1 dB on a synthetic textured image, -4.7 at x 3, and 5.1 dB below it inside a x 3 highlight of an
    image otherwise in [0, 1]). The guard's white fade turns the correction off where a sample nearby reaches 1.5:
    the floor against MHC holds above white (PSNR against the peak k), and a mosaic in [0, 1] is unchanged."""
    img = ss.photo("coffee.png", 96)[None].double()

    def psnr(out, truth, peak, region=(slice(10, -10), slice(10, -10))):
        return float(10 * torch.log10(peak ** 2 / ((out - truth)[..., region[0], region[1]] ** 2).mean()))

    for k in (1.5, 2.0, 3.0):
        truth = img * k
        raw = mosaic(truth).float()
        ours = psnr(demosaic(raw, "RGGB", method=method).double(), truth, k)
        base = psnr(demosaic(raw, "RGGB", method="malvar2004").double(), truth, k)
        assert ours >= base - 0.1, (k, ours, base)
    truth = img.clone()
    truth[..., 30:70, 30:70] *= 3  # a highlight
    raw = mosaic(truth).float()
    patch = (slice(32, 68), slice(32, 68))
    ours = psnr(demosaic(raw, "RGGB", method=method).double(), truth, 3.0, patch)
    base = psnr(demosaic(raw, "RGGB", method="malvar2004").double(), truth, 3.0, patch)
    assert ours >= base - 0.1, (ours, base)
    opts = dict(learned.PRETRAINED_GUARDS[learned.LEARNED_METHODS[method]])
    assert opts.pop("white_fade") == 1.5
    raw = mosaic(img).float()  # within [0, 1]: the fade's weight is exactly 1
    residual = torch.randn(1, 3, 96, 96, generator=torch.Generator().manual_seed(0))
    assert torch.equal(learned.guard_residual(raw, residual, **opts, white_fade=1.5),
                       learned.guard_residual(raw, residual, **opts))


def _floor_failures(images):
    res = ss.score(images, {"mhc": lambda raw, p: demosaic(raw, p, method="malvar2004"),
                            "learned": lambda raw, p: demosaic(raw, p, method="learned")})
    return {n: round(res["learned"][n] - res["mhc"][n], 2) for n, _ in images
            if res["learned"][n] < res["mhc"][n] - 0.1}


def test_never_below_malvar_on_stress_subset():
    # a CI-sized subset of the stress set: three photographs in every variant, two whole photographs, two
    # generator scenes (one with chromatic fine detail) in their variants, and the grey and red-cyan patterns
    images = ss.stress_set(96, n_natural=2, photos=("retina.jpg", "coffee.png", "ihc.png"),
                           whole_variants=("plain", "red"), with_patterns=True)
    images = [(n, x) for n, x in images if n not in KNOWN_BELOW_MHC]
    assert len(images) >= 40
    assert _floor_failures(images) == {}


@pytest.mark.xfail(strict=True, reason="known: green-magenta fine patterns (Bayer ambiguity; model card)")
def test_never_below_malvar_on_green_magenta_patterns():
    images = [(n, x) for n, x in ss.patterns(96) if n in KNOWN_BELOW_MHC]
    assert _floor_failures(images) == {}


def _chromatic_high_frequency(n: int = 96):
    """Synthetic content found below MHC by an audit (2026-11-30; not in the stress set): a red-green grating of
    0.15 cycles/pixel, and colour noise of 32 x 32 samples upsampled bilinearly to n (8-bit)."""
    import math

    import torch.nn.functional as F

    y, x = torch.meshgrid(torch.arange(n, dtype=torch.float64), torch.arange(n, dtype=torch.float64), indexing="ij")
    s = 0.5 + 0.5 * torch.cos(2 * math.pi * 0.15 * (x + 0.3 * y))
    noise = F.interpolate(torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(1), dtype=torch.float64),
                          size=(n, n), mode="bilinear", align_corners=False)[0]
    return [("red_green_grating", (torch.stack([1 - s, s, 0 * s]) * 255).round() / 255),
            ("smooth_colour_noise", (noise * 255).round() / 255)]


@pytest.mark.xfail(strict=True, reason="known: chromatic high-frequency synthetic content (model card)")
def test_never_below_malvar_on_chromatic_high_frequency_content():
    """Measured: -3.2 dB on the red-green grating (MHC 17.3 dB), -1.0 dB on the upsampled colour noise (MHC 22.0):
    like the green-magenta patterns, fine chroma the mosaic cannot tell from other content; every photograph
    scored (the stress set's, the held-out ones of benchmarks/) stays above the floor."""
    assert _floor_failures(_chromatic_high_frequency()) == {}


def test_joint_low_noise_gate():
    """The shipped joint network's low-noise gate (learned.PRETRAINED_GATES): a mosaic's noise against its mean
    level, r = sqrt(b + a m) / m, weighs in the noise-free network with w = 1 - r / relative_max (clamped): exactly
    the noise-free network for a noise-free level, exactly the bare-gated joint network from relative_max on, the
    convex blend between, whatever the noise kind; the bare network (guard=False) has no gate. (The high-noise gate,
    tested below, is taken off here.)"""
    import copy

    shipped = learned.load_pretrained("joint_denoise")
    expert, noise_free = shipped.level_gate["expert"], learned.load_pretrained("noise_free")
    assert expert.guard == noise_free.guard and expert.correction_scale == noise_free.correction_scale
    assert all(torch.equal(a, b) for a, b in zip(expert.state_dict().values(), noise_free.state_dict().values()))
    assert learned.load_pretrained("joint_denoise", guard=False).level_gate is None
    joint = copy.copy(shipped)
    joint.level_gate = gate = {k: v for k, v in shipped.level_gate.items() if k != "classical"}
    r_max = gate["relative_max"]
    g = torch.Generator().manual_seed(3)
    raw = torch.rand(2, 1, 32, 32, generator=g) * 0.6 + 0.2
    m = raw.double().mean((1, 2, 3))
    nf = learned.demosaic_learned(raw, model=gate["expert"])

    def joint_alone(noise):  # the guarded joint network without its gate
        saved, joint.level_gate = joint.level_gate, None
        try:
            return learned.demosaic_learned(raw, model=joint, noise=noise)
        finally:
            joint.level_gate = saved

    zero = learned.noise_features(0.0, 0.0).float().expand(2, 2)
    torch.testing.assert_close(learned.demosaic_learned(raw, model=joint, noise=zero), nf, rtol=0, atol=1e-7)
    high = learned.noise_features(0.0, (1.5 * r_max * m) ** 2).float()
    assert torch.equal(learned.demosaic_learned(raw, model=joint, noise=high), joint_alone(high))
    # between: item 0 at half relative_max in white noise, item 1 in shot noise
    a1 = float((0.5 * r_max * m[1]) ** 2 / m[1])
    mid = learned.noise_features(torch.tensor([0.0, a1]), torch.stack([(0.5 * r_max * m[0]) ** 2,
                                                                      torch.tensor(0.0, dtype=torch.float64)])).float()
    w = learned.level_gate_weight(raw, mid, relative_max=r_max)
    torch.testing.assert_close(w, torch.tensor([0.5, 0.5], dtype=torch.float64), rtol=0, atol=1e-6)
    expected = 0.5 * nf + 0.5 * joint_alone(mid)
    torch.testing.assert_close(learned.demosaic_learned(raw, model=joint, noise=mid), expected, rtol=0, atol=1e-6)


def test_classical_gate_weight_ramp():
    """The high-noise gate's weight: 0 up to sigma_start, linear to weight_max at sigma_full, constant beyond, with
    sigma = sqrt(b + a mean(x)) (both kinds of noise at the same level give the same weight)."""
    raw = torch.full((1, 1, 8, 8), 0.25)
    for sigma, expected in ((0.0, 0.0), (0.02, 0.0), (0.035, 0.3), (0.05, 0.6), (0.2, 0.6)):
        white = learned.noise_features(0.0, sigma**2)
        shot = learned.noise_features(sigma**2 / 0.25, 0.0)
        for noise in (white, shot):
            w = learned.classical_gate_weight(raw, noise, 0.02, 0.05, 0.6)
            assert float(w) == pytest.approx(expected, abs=1e-12)
    for bad in ((0.05, 0.05, 0.5), (-0.01, 0.05, 0.5), (0.01, 0.05, 0.0), (0.01, 0.05, 1.5)):
        with pytest.raises(ValueError, match="sigma_start, sigma_full, weight_max"):
            learned.classical_gate_weight(raw, white, *bad)


def test_classical_expert_is_the_benchmark_baseline(tmp_path):
    """The classical expert is the demosaic benchmark's sequential baseline (nlmeans on the CFA sub-planes, then
    Menon 2007): on the benchmark's noisy mosaic it scores what evaluate_demosaic reports for that baseline."""
    from PIL import Image

    from isettorch.isp.evaluation import cpsnr, evaluate_demosaic, noisy_mosaic

    g = np.random.default_rng(4)
    img = (np.clip(np.cumsum(g.normal(0, 6, (48, 48, 3)), 0) + 90, 0, 255)).astype(np.uint8)
    Image.fromarray(img).save(tmp_path / "a.png")
    sigma, shot = 0.01, 0.004
    reported = evaluate_demosaic(tmp_path, "menon2007", "RGGB", 4, denoise="nlmeans", noise_sigma=sigma,
                                 noise_shot=shot, dtype=torch.float64)["mean_cpsnr"]
    truth = torch.from_numpy(img.astype(np.float64) / 255).permute(2, 0, 1)[None]
    raw = noisy_mosaic(mosaic(truth, "RGGB"), sigma, shot, seed=0, index=0)
    out = learned.classical_expert(raw, learned.noise_features(shot, sigma**2))
    assert float(cpsnr(out.clamp(0, 1), truth, 4)[0]) == pytest.approx(reported, abs=1e-6)


def test_demosaic_learned_applies_a_classical_gate():
    """A joint network's high-noise gate: the output is w expert + (1 - w) (the network under its low-noise gate),
    per image, and the expert runs only on the images it is weighed in for (one image below sigma_start keeps the
    network's output bitwise)."""

    net = learned.load_pretrained("joint_denoise")
    gate = {k: v for k, v in net.level_gate.items() if k != "classical"}
    net.level_gate = gate
    g = torch.Generator().manual_seed(5)
    raw = torch.rand(2, 1, 32, 32, generator=g, dtype=torch.float64).float() * 0.5 + 0.25
    noise = learned.noise_features(torch.tensor([0.0, 0.0]), torch.tensor([0.02**2, 0.06**2])).float()
    plain = learned.demosaic_learned(raw, model=net, noise=noise)
    net.level_gate = gate | {"classical": {"sigma_start": 0.03, "sigma_full": 0.09, "weight_max": 0.8,
                                           "denoiser": "nlmeans", "method": "menon2007"}}
    gated = learned.demosaic_learned(raw, model=net, noise=noise)
    assert torch.equal(gated[0], plain[0])
    expert = learned.classical_expert(raw[1:], noise[1:])
    w = 0.8 * (0.06 - 0.03) / (0.09 - 0.03)
    torch.testing.assert_close(gated[1:], w * expert + (1 - w) * plain[1:], rtol=0, atol=1e-6)


def test_classical_detail_weight_against_scipy():
    """The detail-weighted gate's factor, against an independent computation with scipy's uniform filter (its
    'nearest' border is the replicate border): r = std / sqrt(b + a mean) over 5 x 5 pixels of the luminance, the
    factor weight_detail + (weight_max - weight_detail) clamp((r1 - r) / (r1 - r0), 0, 1); weight_max on a constant
    field, weight_detail everywhere on a noise-free mosaic's estimate."""
    from scipy.ndimage import uniform_filter

    g = np.random.default_rng(11)
    img = np.clip(0.4 + np.cumsum(g.normal(0, 0.01, (2, 3, 24, 20)), -1), 0, 1)
    img[:, :, :, :6] = 0.3  # a flat region
    img[:, :, -5:, 8:] = g.normal(-0.05, 0.01, (2, 3, 5, 12))  # a noisy black region: local means below 0
    a, b = np.array([0.01, 0.0]), np.array([1e-6, 0.02**2])
    noise = learned.noise_features(torch.from_numpy(a), torch.from_numpy(b))
    w_max, w_detail, (r0, r1) = 0.9, 0.2, (0.5, 1.5)
    got = learned.classical_detail_weight(torch.from_numpy(img), noise, w_max, w_detail, (r0, r1)).numpy()
    for i in range(2):
        lum = img[i].mean(0)
        mean = uniform_filter(lum, 5, mode="nearest")
        std = np.sqrt(np.maximum(uniform_filter(lum**2, 5, mode="nearest") - mean**2, 0))
        r = std / np.sqrt(b[i] + a[i] * np.maximum(mean, 0))
        expected = w_detail + (w_max - w_detail) * np.clip((r1 - r) / (r1 - r0), 0, 1)
        np.testing.assert_allclose(got[i, 0], expected, rtol=0, atol=1e-9)
    assert got[:, 0, :, :3].min() == pytest.approx(w_max)  # the flat columns, away from the ramp's window
    assert got[0].min() < w_max - 0.1  # the ramp has detail here
    clean = learned.noise_features(0.0, 0.0).expand(2, -1)
    assert np.all(learned.classical_detail_weight(torch.from_numpy(img), clean, w_max, w_detail, (r0, r1)).numpy()
                  == w_detail)
    assert np.isfinite(got).all()
    for bad in (((1.0, 0.5), 0.2, 0.9), ((0.5, 1.5), -0.1, 0.9), ((0.5, 1.5), 0.2, 0.0), ((0.25, np.inf), 0.2, 0.9)):
        with pytest.raises(ValueError, match="detail_r, weight_detail, weight_max"):
            learned.classical_detail_weight(torch.from_numpy(img), noise, bad[2], bad[1], bad[0])
    with pytest.raises(ValueError, match="detail_r: expected two numbers"):
        learned.classical_detail_weight(torch.from_numpy(img), noise, 0.9, 0.2, (0.25,))
    with pytest.raises(ValueError, match="window: expected an odd"):
        learned.classical_detail_weight(torch.from_numpy(img), noise, 0.9, 0.2, (0.5, 1.5), window=4)


def test_demosaic_learned_applies_a_detail_weighted_classical_gate():
    """With ``detail_r`` the high-noise gate weighs the expert per pixel: ramp(sigma) times the detail factor of the
    mean of the two estimates; the images below sigma_start keep the network's output bitwise."""

    net = learned.load_pretrained("joint_denoise")
    gate = {k: v for k, v in net.level_gate.items() if k != "classical"}
    net.level_gate = gate
    g = torch.Generator().manual_seed(6)
    raw = torch.rand(2, 1, 32, 32, generator=g, dtype=torch.float64).float() * 0.5 + 0.25
    raw[..., :, :12] = 0.4  # a flat region, where the factor is weight_max
    noise = learned.noise_features(torch.tensor([0.0, 0.0]), torch.tensor([0.02**2, 0.06**2])).float()
    plain = learned.demosaic_learned(raw, model=net, noise=noise)
    classical = {"sigma_start": 0.03, "sigma_full": 0.09, "weight_max": 0.8, "weight_detail": 0.1,
                 "detail_r": (0.5, 1.5), "denoiser": "nlmeans", "method": "menon2007"}
    net.level_gate = gate | {"classical": classical}
    gated = learned.demosaic_learned(raw, model=net, noise=noise)
    assert torch.equal(gated[0], plain[0])
    expert = learned.classical_expert(raw[1:], noise[1:])
    factor = learned.classical_detail_weight(0.5 * (expert + plain[1:]), noise[1:], 0.8, 0.1, (0.5, 1.5))
    assert factor.min() < 0.5 and factor.max() == pytest.approx(0.8)  # both kinds of region are in the test
    w = (0.06 - 0.03) / (0.09 - 0.03) * factor
    torch.testing.assert_close(gated[1:], w * expert + (1 - w) * plain[1:], rtol=0, atol=1e-6)
    # an odd-sized GBRG mosaic: the gate is computed on the padded RGGB view and cropped back, as the expert is
    net.level_gate = gate
    odd = raw[1:, :, 1:, :-1]  # 31 x 31, GBRG from the RGGB mosaic
    plain = learned.demosaic_learned(odd, "GBRG", model=net, noise=noise[1:])
    net.level_gate = gate | {"classical": classical}
    gated = learned.demosaic_learned(odd, "GBRG", model=net, noise=noise[1:])
    pad = torch.nn.functional.pad
    x = pad(pad(odd, (0, 0, 1, 1), mode="reflect"), (0, 1, 0, 1), mode="reflect")  # RGGB from row 1, whole cells
    expert = learned.classical_expert(x, noise[1:])[..., 1:32, :31]
    factor = learned.classical_detail_weight(0.5 * (expert + plain), noise[1:], 0.8, 0.1, (0.5, 1.5))
    w = 0.5 * factor
    inner = (Ellipsis, slice(3, -3), slice(3, -3))  # (at the edges the box also saw the padding's pixels)
    torch.testing.assert_close(gated[inner], (w * expert + (1 - w) * plain)[inner], rtol=0, atol=1e-6)


def test_shipped_classical_gate_takes_the_expert_on_flat_regions():
    """The shipped joint model's high-noise gate is per pixel: on a mosaic with a flat half and a textured half at
    sigma 0.02 (past the level ramp), the output is the classical expert deep inside the flat half and mostly the
    network on the texture."""
    joint = learned.load_pretrained("joint_denoise")
    g = torch.Generator().manual_seed(9)
    clean = torch.full((1, 1, 48, 48), 0.45)
    clean[..., 24:] = 0.2 + 0.6 * torch.rand(1, 1, 48, 24, generator=g)  # texture far above the noise
    noise = learned.noise_features(0.0, 0.02**2).float()
    raw = clean + 0.02 * torch.randn(clean.shape, generator=g)
    out = learned.demosaic_learned(raw, model=joint, noise=noise)
    expert = learned.classical_expert(raw, noise)
    bare = copy.copy(joint)
    bare.level_gate = {k: v for k, v in joint.level_gate.items() if k != "classical"}
    net = learned.demosaic_learned(raw, model=bare, noise=noise)
    def share(region):  # the expert's weight, in the mean over the region
        return ((out[region] - net[region]).abs().mean() / (expert[region] - net[region]).abs().mean()).item()

    flat = (slice(None), slice(None), slice(8, 40), slice(4, 16))
    tex = (slice(None), slice(None), slice(8, 40), slice(30, 44))
    assert share(flat) > 0.99 and share(tex) < 0.5, (share(flat), share(tex))  # weight_max 1, weight_detail 0.2


def test_classical_gate_dict_is_checked():
    """A malformed high-noise gate is refused naming the key, on every call, also when the gate is off for the
    images given (a noise-free batch)."""
    base = {"sigma_start": 0.0, "sigma_full": 0.01, "weight_max": 1.0, "denoiser": "nlmeans", "method": "menon2007"}
    assert learned.check_classical_gate(base) is base
    for bad, match in (({"weight_detail": 0.2}, "go together"), ({"detail_r": (0.25, 1.0)}, "go together"),
                       ({"detail_R": (0.25, 1.0)}, "unknown \\['detail_R'\\]"),
                       ({"weight_detail": 0.2, "detail_r": (0.25, float("inf"))}, "detail_r, weight_detail"),
                       ({"weight_detail": 0.2, "detail_r": (1.0,)}, "detail_r: expected two numbers"),
                       ({"sigma_full": float("nan")}, "sigma_start, sigma_full, weight_max")):
        with pytest.raises(ValueError, match=match):
            learned.check_classical_gate(base | bad)
    with pytest.raises(ValueError, match="missing \\['method'\\]"):
        learned.check_classical_gate({k: v for k, v in base.items() if k != "method"})
    net = learned.load_pretrained("joint_denoise")
    net.level_gate = dict(net.level_gate) | {"classical": base | {"detail_r": (0.25, 1.0)}}
    with pytest.raises(ValueError, match="model.level_gate\\['classical'\\]: 'weight_detail' and 'detail_r'"):
        learned.demosaic_learned(torch.full((1, 1, 8, 8), 0.5), model=net, noise=learned.noise_features(0.0, 0.0))


def test_relative_level_gate_is_exposure_invariant():
    """The relative low-noise gate reads r = sqrt(b + a m) / m: a frame scaled by k with its noise (a -> k a,
    b -> k^2 b) gets the same weight, and r = r_max / 2 gives 1/2; the absolute gate gives a dark frame more."""
    g = torch.Generator().manual_seed(6)
    raw = torch.rand(1, 1, 16, 16, generator=g, dtype=torch.float64) * 0.5 + 0.25
    m = float(raw.mean())
    a, b = 2e-4, 1e-5
    r = (b + a * m) ** 0.5 / m
    ws = []
    for k in (1.0, 0.25, 0.05):
        noise = learned.noise_features(a * k, b * k * k)
        ws.append(float(learned.level_gate_weight(raw * k, noise, relative_max=2 * r)))
    assert ws == pytest.approx([0.5, 0.5, 0.5], abs=1e-9)
    s_max = 4 * (b + a * m) ** 0.5  # the absolute form: 1 - 1/4 on the frame, 1 - 1/16 two stops under
    bright = float(learned.level_gate_weight(raw, learned.noise_features(a, b), s_max))
    dark = float(learned.level_gate_weight(raw * 0.25, learned.noise_features(a / 4, b / 16), s_max))
    assert bright == pytest.approx(0.75, abs=1e-9) and dark == pytest.approx(1 - 1 / 16, abs=1e-9)
    for bad in ({}, {"sigma_max": 0.01, "relative_max": 0.01}):
        with pytest.raises(ValueError, match="sigma_max, relative_max"):
            learned.level_gate_weight(raw, learned.noise_features(a, b), **bad)


def test_joint_model_noise_none_and_one_row_of_noise():
    """The joint model with noise=None read zeros in the network but skipped its gates (up to 0.26 off the
    noise-free answer); now it is the noise-free mosaic's answer, the noise-free network's. One row of noise
    features (noise_features of two numbers) serves the whole batch (a batch of 3 raised a reshape error). At noise 0
    the noise features' gradient is finite (sqrt at 0 gave NaN)."""
    raw = torch.rand(3, 1, 16, 16, generator=torch.Generator().manual_seed(0))
    zero = learned.noise_features(0.0, 0.0).float()
    none = learned.demosaic_learned(raw, variant="joint_denoise")
    assert torch.equal(none, learned.demosaic_learned(raw, variant="joint_denoise", noise=zero.expand(3, -1)))
    torch.testing.assert_close(none, learned.demosaic_learned(raw, variant="noise_free"), rtol=0, atol=1e-6)
    nz = learned.noise_features(1e-3, 1e-4).float()
    assert nz.shape == (1, 2)
    assert torch.equal(learned.demosaic_learned(raw, variant="joint_denoise", noise=nz),
                       learned.demosaic_learned(raw, variant="joint_denoise", noise=nz.expand(3, -1)))
    z = zero.clone().requires_grad_(True)
    learned.demosaic_learned(raw[:1], variant="joint_denoise", noise=z).sum().backward()
    assert torch.isfinite(z.grad).all()


def test_the_joint_network_runs_a_noise_free_float64_mosaic_as_float32():
    """At noise 0 the noise sigma was clamped to 1.5e-154, not 0: in float64 the high-noise gate's ramp came out
    1.5e-152 > 0 and switched the classical expert on, which refused a mosaic without noise ("'nlmeans' needs a noise
    level"); float32 rounded it to 0."""
    raw = mosaic(torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0)), "RGGB")
    zero = learned.noise_features(0, 0)
    assert learned.mosaic_noise_sigma(raw, zero).tolist() == [0.0]
    assert learned.classical_gate_weight(raw, zero, 0.0, 0.01, 1.0).tolist() == [0.0]
    out32 = learned.demosaic_learned(raw, variant="joint_denoise")
    for noise in (None, zero.double()):
        out64 = learned.demosaic_learned(raw.double(), variant="joint_denoise", noise=noise)
        assert out64.dtype == torch.float64
        assert torch.allclose(out64.float(), out32, atol=1e-5), float((out64.float() - out32).abs().max())


@pytest.mark.parametrize("noise", [(1e-3, 1e-4), (1e-3, 1e-6), (0.0, 1e-4)])
def test_the_joint_model_keeps_a_constant_below_black_with_shot_noise(noise):
    # A constant below black (noise below the black level) with shot noise: the classical expert's Anscombe transform
    # clipped it at -(3a/8 + b/a) and the field came back grey, (-0.10, -0.10, -0.10) for (-0.5, -0.25, -0.125). A
    # constant sub-plane is now its own denoised value.
    from isettorch.isp.denoise import denoise_mosaic

    field = torch.tensor([-0.5, -0.25, -0.125]).view(1, 3, 1, 1).expand(1, 3, 20, 22).contiguous()
    out = learned.demosaic_learned(mosaic(field, "RGGB"), "RGGB", variant="joint_denoise",
                                   noise=learned.noise_features(*noise).float())
    torch.testing.assert_close(out, field, rtol=0, atol=1e-5)
    flat = mosaic(field, "RGGB").double()
    assert torch.equal(denoise_mosaic(flat, "nlmeans", noise_sigma=1e-3, noise_shot=1e-3), flat)
