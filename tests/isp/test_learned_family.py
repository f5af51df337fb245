"""The parts of the speed-error family of learned demosaickers (issue #35 item 3) that need no shipped weights: a
DemosaicNet on top of Menon et al. (2007), and the guard's decimated high-pass."""

from __future__ import annotations

import math
import re

import pytest
import torch
from kornia.filters import gaussian_blur2d

from isettorch.isp import learned
from isettorch.isp.demosaicing import demosaic_menon2007, mosaic


def test_untrained_menon_network_is_menon():
    # the head starts at zero, so the untrained network is its base exactly (the MHC default is covered by the
    # training tests); the base is part of the config a checkpoint stores
    raw = torch.rand(2, 1, 24, 32, generator=torch.Generator().manual_seed(1))
    net = learned.DemosaicNet(channels=4, depth=3, base="menon2007")
    torch.testing.assert_close(net(raw), demosaic_menon2007(raw, "RGGB"), rtol=0, atol=0)
    assert net.config()["base"] == "menon2007"
    assert "base" not in learned.DemosaicNet(channels=4, depth=1).config()  # old checkpoints keep their config
    assert learned.DemosaicNet(**net.config()).base == "menon2007"
    with pytest.raises(ValueError, match="base"):
        learned.DemosaicNet(channels=4, depth=1, base="ahd")


@pytest.mark.parametrize("shape, sigma", [((1, 3, 40, 52), 1.0), ((2, 3, 9, 7), 4.0), ((1, 3, 120, 90), 16.0)])
def test_guard_blur_is_kornias_gaussian_blur(shape, sigma):
    # the guard's Gaussian is two depthwise convolutions with kornia's kernel: kornia's gaussian_blur2d values
    # (replicate border, 2 ceil(3 sigma) + 1 taps), also where the kernel is wider than the image
    x = torch.rand(shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    k = 2 * math.ceil(3 * sigma) + 1
    ref = gaussian_blur2d(x, (k, k), (sigma, sigma), border_type="replicate")
    torch.testing.assert_close(learned._gaussian_blur(x, sigma), ref, rtol=1e-13, atol=1e-15)


def test_decimated_lowpass_approximates_the_gaussian():
    # On a smooth random field (white noise blurred at 6 px), the 8 x 8-pyramid low-pass matches the exact Gaussian
    # of sigma 16 to a few per cent of the low-pass signal away from the borders: both keep the same band (the box
    # and the bilinear interpolation add about d / sqrt(6) = 3.3 px in quadrature to sigma, +2 % in width).
    g = torch.Generator().manual_seed(0)
    x = gaussian_blur2d(torch.randn(1, 3, 200, 264, generator=g, dtype=torch.float64), (37, 37), (6.0, 6.0))
    exact = learned._lowpass(x, 16.0, None)
    fast = learned._lowpass(x, 16.0, 8)
    inner = (..., slice(48, -48), slice(48, -48))
    rel = float((fast - exact)[inner].norm() / exact[inner].norm())
    assert rel < 0.08, rel  # (sigma 14 or 18 exactly: 0.21, 0.13)
    # a constant stays constant (to rounding), whatever the size (199 x 261 is not a multiple of 8)
    c = torch.full((1, 3, 199, 261), 0.37, dtype=torch.float64)
    torch.testing.assert_close(learned._lowpass(c, 16.0, 8), c, rtol=1e-12, atol=0)


def test_fast_guard_keeps_constants_exact_and_checks_its_options():
    field = torch.tensor([0.9, 0.2, 0.1]).view(1, 3, 1, 1).expand(1, 3, 40, 48).contiguous()
    net = learned.DemosaicNet(channels=4, depth=1, base="menon2007",
                              guard={"highpass_sigma_px": 16.0, "highpass_decimation": 8})
    torch.nn.init.normal_(net.head.weight)  # a network whose correction is far from zero
    with torch.no_grad():
        out = net(mosaic(field, "RGGB"))
    assert float((out - field).abs().max()) <= 1e-6
    for bad in (1, 2.5, True):
        with pytest.raises(ValueError, match="highpass_decimation"):
            learned.guard_residual(mosaic(field), torch.zeros_like(field), highpass_decimation=bad)
    with pytest.raises(ValueError, match="highpass_decimation"):  # no coarser than the blur it approximates
        learned.guard_residual(mosaic(field), torch.zeros_like(field), highpass_sigma_px=4.0, highpass_decimation=8)


def test_correction_scale_moves_the_output_linearly_from_the_guarded_base():
    # the guard is linear in the correction it is given (a gate fixed by the mosaic times it, minus its low-pass), so
    # with a correction scale s the output is affine in s: out(s) = out(0) + s (out(1) - out(0)), out(0) is the guarded
    # base (Menon's departure from MHC, guarded), and constants stay exact at any s
    g = torch.Generator().manual_seed(5)
    raw = torch.rand(1, 1, 40, 48, generator=g, dtype=torch.float64)
    net = learned.DemosaicNet(channels=4, depth=2, base="menon2007", guard={"highpass_sigma_px": 4.0,
                                                                        "highpass_decimation": 4}).double()
    torch.nn.init.normal_(net.head.weight, std=0.1, generator=g)
    outs = {}
    with torch.no_grad():
        for s in (0.0, 0.75, 1.0):
            net.correction_scale = s
            outs[s] = net(raw)
        menon = demosaic_menon2007(raw, "RGGB")
        mhc = learned.BASES["malvar2004"](raw)
        base = mhc + learned.guard_residual(raw, menon - mhc, **net.guard)
    assert float((outs[1.0] - outs[0.0]).abs().max()) > 1e-3
    torch.testing.assert_close(outs[0.0], base, rtol=0, atol=1e-12)
    torch.testing.assert_close(outs[0.75], outs[0.0] + 0.75 * (outs[1.0] - outs[0.0]), rtol=0, atol=1e-12)
    field = torch.tensor([0.9, 0.2, 0.1], dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, 40, 48)
    net.correction_scale = 0.75
    with torch.no_grad():
        assert float((net(mosaic(field, "RGGB")) - field).abs().max()) <= 1e-12
    assert learned.DemosaicNet(**net.config()).correction_scale == 0.75  # stored in a checkpoint's config
    assert "correction_scale" not in learned.DemosaicNet(channels=4, depth=1).config()
    for bad in (-0.5, float("nan"), True, "1"):
        with pytest.raises(ValueError, match="correction_scale"):
            learned.DemosaicNet(channels=4, depth=1, correction_scale=bad)


def test_blend_is_the_convex_combination_of_the_guarded_estimates():
    # blend {"method": m, "weight": b}: the output is (1 - b) net + b (MHC + guard(m - MHC)), the guard being linear;
    # constants stay exact, the blend is stored in the config, and bad blends are refused naming the argument
    g = torch.Generator().manual_seed(7)
    raw = torch.rand(1, 1, 40, 48, generator=g, dtype=torch.float64)
    net = learned.DemosaicNet(channels=4, depth=2, guard={"highpass_sigma_px": 4.0}).double()
    torch.nn.init.normal_(net.head.weight, std=0.1, generator=g)
    with torch.no_grad():
        plain = net(raw)
        mhc = learned.BASES["malvar2004"](raw)
        menon = mhc + learned.guard_residual(raw, demosaic_menon2007(raw, "RGGB") - mhc, **net.guard)
        net.blend = {"method": "menon2007", "weight": 0.3}
        blended = net(raw)
        field = torch.tensor([0.2, 0.7, 0.4], dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, 40, 48)
        const = net(mosaic(field, "RGGB"))
    assert float((plain - menon).abs().max()) > 1e-3
    torch.testing.assert_close(blended, 0.7 * plain + 0.3 * menon, rtol=0, atol=1e-12)
    assert float((const - field).abs().max()) <= 1e-12
    assert learned.DemosaicNet(**net.config()).blend == {"method": "menon2007", "weight": 0.3}
    assert "blend" not in learned.DemosaicNet(channels=4, depth=1).config()
    for bad in ({"method": "menon2007", "weight": 1.5}, {"method": "ahd", "weight": 0.1}, {"weight": 0.1},
                {"method": "menon2007", "weight": True}, {"method": ["menon2007"], "weight": 0.1}, "menon2007"):
        with pytest.raises(ValueError, match="blend"):
            learned.DemosaicNet(channels=4, depth=1, blend=bad)


@pytest.mark.skipif(not all(learned.PRETRAINED[v].is_file() for v in learned.LEARNED_METHODS.values()),
                    reason="no shipped checkpoints")
def test_family_methods_run_their_shipped_networks():
    # each registered method is its variant's shipped network under its shipped guard, and the family is ordered by
    # size: tiny < small < the accurate default
    from isettorch.isp.demosaicing import demosaic

    raw = torch.rand(1, 1, 32, 48, generator=torch.Generator().manual_seed(2))
    outs = {}
    for method, variant in learned.LEARNED_METHODS.items():
        net = learned.load_pretrained(variant)
        assert net.guard == learned.PRETRAINED_GUARDS[variant]
        assert net.correction_scale == learned.PRETRAINED_CORRECTION_SCALES.get(variant, 1.0)
        assert learned.load_pretrained(variant, guard=False).correction_scale == 1.0  # the bare network
        assert net.blend == learned.PRETRAINED_BLENDS.get(variant)
        assert learned.load_pretrained(variant, guard=False).blend is None
        outs[method] = demosaic(raw, "GRBG", method=method)
        torch.testing.assert_close(outs[method], learned.demosaic_learned(raw, "GRBG", model=net), rtol=0, atol=0)
    assert float((outs["learned_tiny"] - outs["learned"]).abs().max()) > 1e-3
    sizes = [sum(p.numel() for p in learned.load_pretrained(v).parameters()) for v in ("tiny", "small", "noise_free")]
    assert sizes == sorted(sizes) and len(set(sizes)) == 3


def test_guard_is_relative_to_malvar_for_a_menon_base():
    # Menon's decisions are not linear, so Menon has colour bias of its own (a star field: -0.32/255 of blue); under
    # a guard a Menon-base network's whole departure from MHC is guarded, so its local means are MHC's: on a random
    # texture the mean of (output - MHC) per channel is a small fraction of the mean |Menon - MHC| (it is a
    # high-passed signal), while the unguarded network is Menon itself
    from isettorch.isp.demosaicing import demosaic_malvar2004

    g = torch.Generator().manual_seed(3)
    img = torch.rand(1, 3, 96, 96, generator=g, dtype=torch.float64) ** 3  # sparse bright texture, mean 0.25
    raw = mosaic(img, "RGGB")
    mhc = demosaic_malvar2004(raw, "RGGB", boundary="mirror")
    net = learned.DemosaicNet(channels=4, depth=1, base="menon2007").double()
    with torch.no_grad():
        assert float((net(raw) - demosaic_menon2007(raw, "RGGB")).abs().max()) == 0.0
    net.guard = {"rel": 0.0, "abs": 1e-6, "highpass_sigma_px": 8.0}
    with torch.no_grad():
        dep = (net(raw) - mhc)[..., 24:-24, 24:-24]
        menon_dep = (demosaic_menon2007(raw, "RGGB") - mhc)[..., 24:-24, 24:-24]
    assert float(menon_dep.mean((2, 3)).abs().max()) > 3e-3  # Menon's own mean departure from MHC
    assert float((dep.mean((2, 3)).abs() / menon_dep.abs().mean((2, 3))).max()) < 0.05


def test_every_learned_method_is_a_lazy_name_of_the_registry():
    # the registry knows the learned methods' names before importing isettorch.isp.learned (its _LAZY_METHODS); the
    # two lists must name the same methods, or a new variant would be unknown until the module is imported
    from isettorch.isp.demosaicing import _LAZY_METHODS

    assert set(_LAZY_METHODS) == set(learned.LEARNED_METHODS)
    assert all(module == learned.__name__ for module in _LAZY_METHODS.values())


def test_first_layer_unpacked_matches_the_packed_convolution_and_its_gradients():
    # The network's first layer sees the mosaic's and the base's 2 x 2 cells as channels, pixel_unshuffle's order
    # (torch's own op is the reference), then the noise inputs as constant planes. It is computed as a stride-2
    # 6 x 6 convolution of the full-resolution planes (+ the noise planes' own product): the packed convolution's
    # values and gradients in either memory layout. The output goes back by pixel_shuffle.
    F = torch.nn.functional
    g = torch.Generator().manual_seed(3)
    raw, base = torch.rand(2, 1, 10, 14, generator=g, dtype=torch.float64), torch.rand(2, 3, 10, 14, generator=g,
                                                                                        dtype=torch.float64)
    noise = torch.rand(2, 2, generator=g, dtype=torch.float64)
    net = learned.DemosaicNet(channels=8, depth=3, noise_inputs=2).double()
    torch.nn.init.normal_(net.head.weight, std=0.1)  # a network that corrects its base (the head starts at zero)
    torch.nn.init.normal_(net.body[0].bias, std=0.1)

    def packed(r, b, nz):
        return torch.cat([F.pixel_unshuffle(r, 2), F.pixel_unshuffle(b, 2), nz[:, :, None, None].expand(-1, -1, 5, 7)],
                         1)

    grads, first = [], []
    for path in ("packed", False, True):
        r, nz = raw.clone().requires_grad_(True), noise.clone().requires_grad_(True)
        b = learned.BASES["malvar2004"](r) + base
        net.zero_grad()
        if path == "packed":
            y = net.body[0](packed(r, b, nz))
        else:
            y = learned._first_conv(net.body[0], r, b, nz, channels_last=path)
            assert y.is_contiguous(memory_format=torch.channels_last if path else torch.contiguous_format)
        first.append(y.detach().clone())  # (the body's first ReLU is in place)
        learned._unpack(net.head(net.body[1:](y))).square().sum().backward()
        grads.append((r.grad, nz.grad, net.head.weight.grad.clone(), net.body[0].weight.grad.clone()))
    for y in first[1:]:
        torch.testing.assert_close(y, first[0], rtol=1e-12, atol=1e-12)
    for other in grads[1:]:
        for a, b in zip(grads[0], other):
            torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    y = torch.rand(2, 12, 5, 7, generator=g)
    for y_in in (y, y.contiguous(memory_format=torch.channels_last)):
        torch.testing.assert_close(learned._unpack(y_in), F.pixel_shuffle(y, 2), rtol=0, atol=0)


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-13), (torch.float32, 1e-6)])
@pytest.mark.parametrize("size, decimation", [((16, 20), 4), ((18, 26), 4), ((22, 14), 3), ((16, 20), None)])
def test_guard_in_place_is_the_guard(dtype, tol, size, decimation):
    # DemosaicNet writes its guarded correction over the network's output in inference (no autograd graph): the
    # same values as the out-of-place guard, which training uses (to float rounding: the in-place high-pass
    # subtracts F.interpolate's bilinear weights as it computes them), at sizes that are and are not multiples of
    # the decimation; and the out-of-place one leaves its input alone.
    g = torch.Generator().manual_seed(4)
    raw = torch.rand(1, 1, *size, generator=g, dtype=dtype)
    residual = torch.randn(1, 3, *size, generator=g, dtype=dtype)
    opts = {"rel": 0.1, "abs": 0.03, "window": 5, "power": 4, "highpass_sigma_px": 4.0,
            "highpass_decimation": decimation}
    kept = residual.clone()
    ref = learned.guard_residual(raw, residual, **opts)
    torch.testing.assert_close(residual, kept, rtol=0, atol=0)
    out = learned.guard_residual(raw, residual, **opts, in_place=True)
    assert out.data_ptr() == residual.data_ptr()
    torch.testing.assert_close(out, ref, rtol=0, atol=tol)


@pytest.mark.parametrize("base", ["malvar2004", "menon2007", "menon2007_norefine"])
@pytest.mark.parametrize("scale, blend", [(1.0, None), (0.5, None), (0.875, {"method": "menon2007", "weight": 0.3})])
def test_inference_output_is_the_training_output(base, scale, blend):
    # In inference (no autograd graph) DemosaicNet folds the correction scale and the blend's network weight into
    # the head, sums the classical departures into a fresh estimate and unpacks the correction into it; in training
    # each step is its own tensor. The same function: float64 to 1e-12, and the input is left as it was.
    g = torch.Generator().manual_seed(6)
    raw = torch.rand(2, 1, 18, 22, generator=g, dtype=torch.float64)
    net = learned.DemosaicNet(channels=6, depth=2, base=base, correction_scale=scale, blend=blend,
                              guard=learned.PRETRAINED_GUARDS["tiny"]).double()
    torch.nn.init.normal_(net.head.weight, std=0.1, generator=g)
    torch.nn.init.normal_(net.head.bias, std=0.01, generator=g)
    for guard in (net.guard, None):
        net.guard = guard
        recorded = net(raw.clone().requires_grad_(True))
        assert recorded.requires_grad
        kept = raw.clone()
        with torch.no_grad():
            out = net(raw)
        torch.testing.assert_close(raw, kept, rtol=0, atol=0)
        torch.testing.assert_close(out, recorded.detach(), rtol=1e-12, atol=1e-12)


def test_gate_curvature_is_the_mean_absolute_second_difference():
    # |d2/dx2| + |d2/dy2| averaged over the planes, each edge row / column repeating its neighbour's (replicate),
    # against the second differences written out as a convolution; zero on constant planes at any value; differentiable
    F = torch.nn.functional
    g = torch.Generator().manual_seed(7)
    for shape in ((2, 4, 6, 9), (1, 4, 2, 6), (1, 4, 6, 2), (1, 4, 2, 2)):
        x = torch.rand(shape, generator=g, dtype=torch.float64)
        ref = torch.zeros(shape[0], 1, *shape[-2:], dtype=torch.float64)
        c = shape[1]
        for kernel, pad in (([[1.0, -2.0, 1.0]], (1, 1, 0, 0)), ([[1.0], [-2.0], [1.0]], (0, 0, 1, 1))):
            k = torch.tensor(kernel, dtype=torch.float64)
            if x.shape[-1] >= k.shape[1] and x.shape[-2] >= k.shape[0]:
                d = F.conv2d(x, k.expand(c, 1, *k.shape), groups=c).abs().mean(1, keepdim=True)
                ref = ref + F.pad(d, pad, mode="replicate")
        torch.testing.assert_close(learned._curvature(x), ref, rtol=1e-12, atol=1e-15)
    assert learned._curvature(torch.full((1, 4, 7, 9), 0.3711)).abs().max() == 0
    x = torch.rand(1, 4, 6, 7, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: learned._curvature(t + 0.5 * t.roll(1, -1) ** 2), (x,))


@pytest.mark.parametrize("opts", [{"highpass_sigma_px": 4.0, "highpass_decimation": 4}, {"highpass_sigma_px": 2.0}])
def test_guard_gradients_match_finite_differences(opts):
    # training through the guard (a camera in the loop, the guard in the loss) needs its gradients with respect to
    # the mosaic (through the gate) and to the correction (through the gate's product and the high-pass)
    g = torch.Generator().manual_seed(8)
    raw = torch.rand(1, 1, 12, 16, generator=g, dtype=torch.float64, requires_grad=True)
    residual = torch.randn(1, 3, 12, 16, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda r, c: learned.guard_residual(r, c, **opts), (raw, residual))


def test_box_mean_matches_avg_pool_with_replicate_border():
    x = torch.rand(2, 4, 9, 13, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    for window in (1, 3, 5, 7):
        p = window // 2
        ref = torch.nn.functional.avg_pool2d(torch.nn.functional.pad(x, (p, p, p, p), mode="replicate"), window, 1)
        torch.testing.assert_close(learned._box(x, window), ref, rtol=1e-12, atol=1e-14)


def test_guard_relative_to_the_base_keeps_the_base_where_it_gates_off():
    # guard["reference"] = "base": out = base + highpass(gate * s * net), the base (here Menon without refining)
    # where the gate is 0; MHC is not computed. Checked against that formula written out, in training (autograd)
    # and in inference (the in-place path), and on a constant colour field (exact: Menon is exact on constants).
    g = torch.Generator().manual_seed(7)
    raw = torch.rand(1, 1, 40, 48, generator=g, dtype=torch.float64)
    guard = {"highpass_sigma_px": 8.0, "highpass_decimation": 4, "reference": "base"}
    net = learned.DemosaicNet(channels=4, depth=2, base="menon2007_norefine", guard=guard,
                              correction_scale=0.5).double()
    torch.nn.init.normal_(net.head.weight, std=0.1, generator=g)
    bare = learned.DemosaicNet(**{**net.config(), "guard": None, "correction_scale": 1.0}).double()
    bare.load_state_dict(net.state_dict())
    with torch.no_grad():
        want = (demosaic_menon2007(raw, "RGGB", refine=False) + learned.guard_residual(
            raw, 0.5 * (bare(raw) - demosaic_menon2007(raw, "RGGB", refine=False)),
            **{k: v for k, v in guard.items() if k != "reference"}))
        fast = net(raw)
    trained = net(raw)  # autograd records this pass: the out-of-place path
    assert trained.requires_grad
    torch.testing.assert_close(fast, want, rtol=0, atol=1e-12)
    torch.testing.assert_close(trained.detach(), want, rtol=0, atol=1e-12)
    mhc_ref = learned.DemosaicNet(**{**net.config(), "guard": {**guard, "reference": "malvar2004"}}).double()
    mhc_ref.load_state_dict(net.state_dict())
    with torch.no_grad():
        assert float((mhc_ref(raw) - fast).abs().max()) > 1e-4  # another function
        field = torch.tensor([0.9, 0.2, 0.1], dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, 40, 48)
        assert float((net(mosaic(field.contiguous(), "RGGB")) - field).abs().max()) <= 1e-12
    with pytest.raises(ValueError, match="reference"):
        learned.DemosaicNet(channels=4, depth=1, guard={"reference": "menon2007"})


@pytest.mark.parametrize("base", sorted(learned.BASES))
def test_first_layer_folds_the_mosaic_into_the_base_exactly_where_the_base_keeps_the_samples(base):
    # In inference the first layer reads only the base, the mosaic's taps added to those of the colour each samples:
    # every base keeps each RGGB sample exactly (so the fold is the same sum), and the two first layers agree.
    g = torch.Generator().manual_seed(11)
    raw = torch.rand(2, 1, 14, 18, generator=g, dtype=torch.float64)
    b = learned.BASES[base](raw)
    for c, (dy, dx) in ((0, (0, 0)), (1, (0, 1)), (1, (1, 0)), (2, (1, 1))):
        torch.testing.assert_close(b[:, c, dy::2, dx::2], raw[:, 0, dy::2, dx::2], rtol=0, atol=0)
    net = learned.DemosaicNet(channels=8, depth=2, noise_inputs=1).double()
    torch.nn.init.normal_(net.body[0].bias, std=0.1, generator=g)
    noise = torch.rand(2, 1, generator=g, dtype=torch.float64)
    for channels_last in (False, True):
        plain = learned._first_conv(net.body[0], raw, b, noise, channels_last=channels_last)
        folded = learned._first_conv(net.body[0], raw, b, noise, channels_last=channels_last, fold_raw=True)
        torch.testing.assert_close(folded, plain, rtol=0, atol=1e-13)


def test_head_computes_only_its_nonzero_channels_with_the_same_values():
    # A noise-free network's head has exact zeros for the corrections at the mosaic's own samples; inference computes
    # only the other channels (padded to a multiple of 8 on CPU) and unpacks them where they belong: the same
    # output as the full head, including a head with no nonzero channel at all.
    F = torch.nn.functional
    g = torch.Generator().manual_seed(12)
    x = torch.rand(2, 8, 5, 7, generator=g, dtype=torch.float64)
    head = torch.nn.Conv2d(8, 12, 3, padding=1).double()
    with torch.no_grad():
        head.weight[[0, 5, 6, 11]] = 0
        head.bias[[0, 5, 6, 11]] = 0
        head.bias[3] = 0  # a used channel with a zero bias stays used
        full = F.pixel_shuffle(head(x), 2) * 0.5
        add = torch.rand(2, 3, 10, 14, generator=g, dtype=torch.float64)
        y, channels = learned._head_forward(head, x, 0.5)
        assert channels == [1, 2, 3, 4, 7, 8, 9, 10] and y.shape[1] == 8
        torch.testing.assert_close(learned._unpack(y, channels=channels), full, rtol=0, atol=1e-15)
        torch.testing.assert_close(learned._unpack(y, add_to=add.clone(), channels=channels), add + full, rtol=0,
                                   atol=1e-15)
        y, channels = learned._head_forward(head, x, 0.0)
        assert channels == [] and float(learned._unpack(y, channels=channels).abs().max()) == 0.0
        head.bias[[0, 5, 6, 11]] = 1.0  # every channel used: all computed, None
        y, channels = learned._head_forward(head, x)
        assert channels is None and y.shape[1] == 12


@pytest.mark.parametrize("shape", [(3, 2), (2,), (4,), (2, 1, 2)])
def test_noise_features_of_the_wrong_shape_are_named_before_the_network_runs(shape):
    """A [3, 2] for two mosaics was reported as the (2, 3) it was reshaped to; a [4] or [2, 1, 2] failed with an
    IndexError after the network had run (learned-model audit, 2026-12-01)."""
    with pytest.raises(ValueError, match=rf"noise: expected shape \[B, noise_inputs\] .* for 2 mosaic\(s\), got "
                                         rf"{re.escape(str(shape))}"):
        learned.demosaic_learned(torch.rand(2, 1, 16, 16), variant="joint_denoise", noise=torch.full(shape, 0.5))


def test_one_mosaic_of_shape_h_w_is_a_batch_of_one_for_its_noise():
    """An [H, W] mosaic's H was taken for the batch: a [16, 2] noise for a 16 x 16 mosaic passed the check."""
    with pytest.raises(ValueError, match=r"noise: expected shape \[B, noise_inputs\] .* for 1 mosaic\(s\), got "
                                         r"\(16, 2\)"):
        learned.demosaic_learned(torch.rand(16, 16), variant="joint_denoise", noise=torch.full((16, 2), 0.5))


def test_a_noise_level_beyond_the_mosaics_full_scale_is_refused():
    """a = 1000 (features [316, 0]) was accepted: the shipped joint network's output grows with its noise input, and
    its gate let the result through (-23.5..10.4 for a smooth image in [0.4, 0.5]). A noise std at white above the
    full scale, a + b > 1, is refused; at a + b = 1 the classical expert still holds the output inside [0.4, 0.53]."""
    g = torch.Generator().manual_seed(1)
    img = torch.nn.functional.avg_pool2d(torch.rand(1, 3, 32, 32, generator=g), 3, 1, 1)
    raw = mosaic(img, "RGGB")
    for a, b in ((1000.0, 0.0), (0.0, 9.0), (0.6, 0.6)):
        with pytest.raises(ValueError, match=r"^noise: expected a noise level within the mosaic's full scale, "
                                             r"a \+ b <= 1"):
            learned.demosaic_learned(raw, variant="joint_denoise", noise=learned.noise_features(a, b).float())
    out = learned.demosaic_learned(raw, variant="joint_denoise", noise=learned.noise_features(1.0, 0.0).float())
    assert float(out.min()) > img.min() - 0.05 and float(out.max()) < img.max() + 0.05


def test_a_model_of_another_dtype_is_named():
    """torch's "Input type (double) and bias type (float) should be the same" named neither argument."""
    with pytest.raises(ValueError, match=r"model: its weights are torch.float32, the mosaic raw is torch.float64"):
        learned.demosaic_learned(torch.rand(1, 1, 16, 16, dtype=torch.float64), model=learned.load_pretrained())


def test_noise_features_have_finite_gradients_at_zero_noise():
    # [sqrt(a) 10, sqrt(b) 100]: sqrt's derivative at 0 was inf (NaN through the network) for a = 0 or b = 0. Now 0
    # there, and d/db sqrt(b) 100 = 50 / sqrt(b) elsewhere (5000 at b = 1e-4).
    for av, bv, want in ((0.0, 1e-4, (0.0, 5000.0)), (1e-3, 0.0, (5 / math.sqrt(1e-3), 0.0)), (0.0, 0.0, (0.0, 0.0))):
        a = torch.tensor(av, dtype=torch.float64, requires_grad=True)
        b = torch.tensor(bv, dtype=torch.float64, requires_grad=True)
        learned.noise_features(a, b).sum().backward()
        assert (float(a.grad), float(b.grad)) == pytest.approx(want, rel=1e-12)


def test_mosaic_reconstruction_net_names_what_it_cannot_take():
    # each was a torch-internal RuntimeError naming no argument
    from isettorch.isp.mosaic_net import MosaicReconstructionNet

    def onehot(h, w):
        idx = torch.tensor([[0, 1], [2, 3]]).repeat((h + 1) // 2, (w + 1) // 2)[:h, :w]
        return torch.nn.functional.one_hot(idx, 4).permute(2, 0, 1).float()

    net = MosaicReconstructionNet(4, width=8, depth=2).eval()
    ctx = MosaicReconstructionNet(4, width=8, depth=2, context_scale=4).eval()
    with pytest.raises(ValueError, match="raw: expected a mosaic of at least 2 x 2 pixels"):
        net(torch.rand(1, 1, 1, 8), onehot(1, 8))
    with pytest.raises(ValueError, match="raw: expected the network's dtype torch.float32, got torch.float64"):
        net(torch.rand(1, 1, 8, 8, dtype=torch.float64), onehot(8, 8))
    with pytest.raises(ValueError, match="weights: expected 1 or 2 maps"):
        net(torch.rand(2, 1, 8, 8), onehot(8, 8)[None].expand(3, -1, -1, -1))
    with pytest.raises(ValueError, match="raw: expected a mosaic of at least 5 x 5 pixels"):
        ctx(torch.rand(1, 1, 3, 5), onehot(3, 5))
    assert ctx(torch.rand(1, 1, 5, 5), onehot(5, 5)).shape == (1, 3, 5, 5)
