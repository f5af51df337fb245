"""Demosaic methods against colour-demosaicing 0.2 on the same input, and invariants: constant images, sampled
values kept, batching, Bayer-order consistency under a one-pixel shift, gradients, input errors."""

from __future__ import annotations

import importlib

import colour_demosaicing as cd
import numpy as np
import pytest
import torch
from scipy import ndimage
from torch import nn

from isettorch.isp import (
    METHODS,
    Demosaic,
    demosaic,
    demosaic_bilinear,
    demosaic_generic,
    demosaic_malvar2004,
    demosaic_menon2007,
    demosaic_nearest,
    demosaic_nearest_cfa,
    get_method,
    mosaic,
    register_method,
)

# the sub-package with the method registry
demosaic_pkg = importlib.import_module("isettorch.isp.demosaicing")
PATTERNS = ["RGGB", "BGGR", "GRBG", "GBRG"]
BUILTIN = ["nearest", "bilinear", "malvar2004", "menon2007"]
REFERENCE = {
    "bilinear_colour": (METHODS["bilinear_colour"], cd.demosaicing_CFA_Bayer_bilinear),
    "malvar2004": (demosaic_malvar2004, cd.demosaicing_CFA_Bayer_Malvar2004),
    "menon2007": (demosaic_menon2007, cd.demosaicing_CFA_Bayer_Menon2007),
}


def _raw(shape, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=g, dtype=dtype)


def _to_np(t):
    return t[0].permute(1, 2, 0).numpy()


@pytest.mark.parametrize("method", sorted(REFERENCE))
@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("shape", [(2, 4), (7, 5), (24, 31)])
def test_matches_colour_demosaicing(method, pattern, shape):
    ours, ref = REFERENCE[method]
    raw = _raw((1, 1, *shape), seed=sum(shape))
    expected = ref(raw[0, 0].numpy(), pattern)
    np.testing.assert_allclose(_to_np(ours(raw, pattern)), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_bilinear_default_differs_from_colour_demosaicing_only_on_the_border(pattern):
    raw = _raw((1, 1, 12, 14), seed=3)
    ours = _to_np(demosaic_bilinear(raw, pattern))
    ref = cd.demosaicing_CFA_Bayer_bilinear(raw[0, 0].numpy(), pattern)
    np.testing.assert_array_equal(ours[1:-1, 1:-1], ref[1:-1, 1:-1])
    # everywhere, border included, ours is the normalised convolution (Knutsson & Westin 1993) of each channel's
    # samples with the tent (R, B) or the cross (G), zero outside the image: scipy
    masks = np.zeros((3, 12, 14))
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        masks["RGB".index(pattern[k]), dy::2, dx::2] = 1
    tent = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])
    cross = np.array([[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]])
    x = raw[0, 0].numpy()
    normalised = np.stack([ndimage.convolve(x * m, k, mode="constant") / ndimage.convolve(m, k, mode="constant")
                           for m, k in zip(masks, (tent, cross, tent), strict=True)], -1)
    np.testing.assert_allclose(ours, normalised, rtol=0, atol=1e-12)
    # colour-demosaicing's reflected border holds too few or too many samples of a channel under its fixed kernel
    # weights (too dark or too bright); ours divides by the weight that fell on samples.
    assert np.abs(ref - ours).max() > 1e-2
    const = torch.full((1, 1, 6, 6), 0.5, dtype=torch.float64)
    assert demosaic_bilinear(const, pattern, normalize_border=False).std() > 0.05


@pytest.mark.parametrize("pattern", PATTERNS)
def test_generic_is_bilinear_on_bayer(pattern):
    raw = _raw((2, 1, 9, 10), seed=4)
    idx = demosaic_pkg.bayer_index_map(pattern)
    # Equal away from the one-pixel border (there the 3x3 tent also sees reflected diagonal samples).
    ref = demosaic_bilinear(raw, pattern)[..., 1:-1, 1:-1]
    torch.testing.assert_close(demosaic_generic(raw, idx, 3)[..., 1:-1, 1:-1], ref, rtol=0, atol=1e-14)
    torch.testing.assert_close(demosaic(raw, idx, "bilinear")[..., 1:-1, 1:-1], ref, rtol=0, atol=1e-14)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("method", BUILTIN)
@pytest.mark.parametrize("pattern", PATTERNS)
def test_constant_image_is_returned(method, pattern, dtype):
    raw = torch.full((2, 1, 11, 10), 0.37, dtype=dtype)
    out = demosaic(raw, pattern, method)
    assert out.shape == (2, 3, 11, 10) and out.dtype == dtype
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    torch.testing.assert_close(out, torch.full_like(out, 0.37), rtol=0, atol=tol)


@pytest.mark.parametrize("index_map,channels", [([[0, 1], [3, 2]], 4), ([[0, 1, 2], [3, 4, 5], [6, 7, 8]], 9),
                                                ([[0, 1, 1], [1, 2, 1]], 3)])
def test_generic_cfa_constant_and_ramp(index_map, channels):
    idx = torch.tensor(index_map)
    const = torch.full((1, 1, 13, 14), 0.25, dtype=torch.float64)
    for fn in (demosaic_generic, demosaic_nearest_cfa):
        torch.testing.assert_close(fn(const, idx, channels), const.expand(1, channels, 13, 14), rtol=0, atol=1e-15)
    if channels in (4, 9):  # one sample per period per channel: the tent is bilinear interpolation, exact on ramps
        y, x = torch.meshgrid(torch.arange(20.0, dtype=torch.float64), torch.arange(21.0, dtype=torch.float64),
                              indexing="ij")
        ramp = (0.1 + 0.03 * y - 0.02 * x)[None, None]
        ph, pw = idx.shape
        out = demosaic_generic(ramp, idx, channels)[..., ph:-ph, pw:-pw]
        torch.testing.assert_close(out, ramp[..., ph:-ph, pw:-pw].expand_as(out), rtol=0, atol=1e-14)


@pytest.mark.parametrize("method", BUILTIN)
@pytest.mark.parametrize("pattern", PATTERNS)
def test_sampled_values_are_kept(method, pattern):
    raw = _raw((2, 1, 10, 12), seed=5)
    torch.testing.assert_close(mosaic(demosaic(raw, pattern, method), pattern), raw, rtol=0, atol=1e-14)


def test_nearest_by_hand():
    # RGGB [[r, g1], [g2, b]]: copies come from the left/above; on the top/left border from one period further in.
    raw = torch.tensor([[[[1.0, 2.0], [3.0, 4.0]]]])
    out = demosaic_nearest(raw, "RGGB")[0]
    torch.testing.assert_close(out[0], torch.full((2, 2), 1.0))
    torch.testing.assert_close(out[1], torch.tensor([[2.0, 2.0], [3.0, 3.0]]))
    torch.testing.assert_close(out[2], torch.full((2, 2), 4.0))
    # Odd width: the third column copies from its own left neighbourhood.
    raw = torch.tensor([[[[1.0, 2.0, 5.0], [3.0, 4.0, 6.0]]]])
    out = demosaic_nearest(raw, "RGGB")[0]
    torch.testing.assert_close(out[2], torch.tensor([[4.0, 4.0, 4.0], [4.0, 4.0, 4.0]]))
    torch.testing.assert_close(out[0], torch.tensor([[1.0, 1.0, 5.0], [1.0, 1.0, 5.0]]))


@pytest.mark.parametrize("method", BUILTIN)
def test_batched_equals_one_at_a_time(method):
    raw = _raw((3, 1, 16, 18), seed=6)
    batched = demosaic(raw, "GBRG", method)
    single = torch.cat([demosaic(raw[i:i + 1], "GBRG", method) for i in range(3)])
    torch.testing.assert_close(batched, single, rtol=0, atol=1e-15)


@pytest.mark.parametrize("method", BUILTIN)
@pytest.mark.parametrize("dy,dx,shifted", [(0, 1, "GRBG"), (1, 0, "GBRG"), (1, 1, "BGGR")])
def test_shifting_the_image_changes_the_pattern(method, dy, dx, shifted):
    # An RGGB mosaic without its first row/column is a GRBG/GBRG/BGGR mosaic of the shifted scene: away from the
    # borders the demosaiced images must coincide.
    raw = _raw((1, 1, 40, 42), seed=7)
    full = demosaic(raw, "RGGB", method)[..., dy:, dx:]
    part = demosaic(raw[..., dy:, dx:], shifted, method)
    m = 12
    torch.testing.assert_close(part[..., m:-m, m:-m], full[..., m:-m, m:-m], rtol=0, atol=1e-14)


@pytest.mark.parametrize("method", ["nearest", "bilinear", "malvar2004"])
def test_gradcheck_linear_methods(method):
    raw = _raw((2, 1, 6, 7), seed=8).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda r: demosaic(r, "GRBG", method), (raw,), fast_mode=True)


def test_gradcheck_generic_and_colour_border_bilinear():
    raw = _raw((1, 1, 6, 6), seed=9).requires_grad_(True)
    idx = torch.tensor([[0, 1, 2], [2, 0, 1]])
    assert torch.autograd.gradcheck(lambda r: demosaic_generic(r, idx, 3), (raw,), fast_mode=True)
    assert torch.autograd.gradcheck(lambda r: demosaic_bilinear(r, "BGGR", normalize_border=False), (raw,),
                                     fast_mode=True)


def test_menon_gradients():
    # Piecewise linear in the raw values: away from direction ties (measure zero) gradcheck holds.
    raw = _raw((1, 1, 8, 9), seed=10).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda r: demosaic_menon2007(r, "RGGB"), (raw,), fast_mode=True)
    demosaic_menon2007(raw, "GBRG").square().sum().backward()
    assert torch.isfinite(raw.grad).all() and (raw.grad.abs() > 0).float().mean() > 0.9


@pytest.mark.parametrize("method", BUILTIN)
def test_float32_agrees_with_float64(method):
    raw = _raw((1, 1, 20, 20), seed=11)
    out64 = demosaic(raw, "RGGB", method)
    out32 = demosaic(raw.float(), "RGGB", method)
    assert out32.dtype == torch.float32
    torch.testing.assert_close(out32.double(), out64, rtol=0, atol=1e-5)


def test_device_agnostic_on_meta():
    # The meta device fails on any tensor created on the CPU and mixed in: a cheap check for "any device".
    raw = torch.empty(2, 1, 16, 18, device="meta")
    for method in [*BUILTIN, "bilinear_colour"]:
        out = demosaic(raw, "GRBG", method)
        assert out.device.type == "meta" and out.shape == (2, 3, 16, 18)
    assert demosaic_generic(raw, torch.tensor([[0, 1], [3, 2]]), 4).shape == (2, 4, 16, 18)
    assert demosaic_nearest_cfa(raw, torch.tensor([[0, 1, 2]]), 3).shape == (2, 3, 16, 18)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("method", BUILTIN)
def test_cuda_matches_cpu(method):
    raw = _raw((2, 1, 32, 32), seed=12)
    torch.testing.assert_close(demosaic(raw.cuda(), "RGGB", method).cpu(), demosaic(raw, "RGGB", method),
                               rtol=0, atol=1e-12)


def test_bad_input_errors():
    raw = _raw((1, 1, 8, 8))
    with pytest.raises(ValueError, match="pattern.*'RGBX'"):
        demosaic(raw, "RGBX")
    with pytest.raises(ValueError, match=r"raw.*\(B, 1, H, W\).*\(1, 3, 8, 8\)"):
        demosaic(raw.expand(1, 3, 8, 8), "RGGB")
    with pytest.raises(TypeError, match="raw.*floating"):
        demosaic((raw * 255).long(), "RGGB")
    with pytest.raises(ValueError, match="method.*'bicubic'"):
        demosaic(raw, "RGGB", "bicubic")
    with pytest.raises(ValueError, match="index_map.*channels \\[2\\]"):
        demosaic_generic(raw, torch.tensor([[0, 1], [1, 0]]), 3)
    with pytest.raises(ValueError, match="method.*index-map"):
        demosaic(raw, torch.tensor([[0, 1], [1, 2]]), "menon2007")


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_samples_are_refused_by_every_method(bad):
    # a NaN or Inf sample is a clear error, not spread over the output (MHC over 5 x 5 pixels, a learned method over
    # the whole image through its guard's local means); the Bayer methods, learned ones included, and index maps
    from isettorch.isp.evaluation import available_methods
    from isettorch.isp.learned import demosaic_learned

    raw = _raw((1, 1, 8, 8)).float()
    raw[0, 0, 3, 4] = bad
    for method in available_methods():
        with pytest.raises(ValueError, match="raw: expected finite values, found 1 NaN/Inf"):
            demosaic(raw, "RGGB", method)
    with pytest.raises(ValueError, match="raw: expected finite values"):
        demosaic(raw, torch.tensor([[0, 1], [1, 2]]), "bilinear")
    with pytest.raises(ValueError, match="raw: expected finite values"):
        demosaic_learned(raw)


def test_register_method_and_module_plugin():
    class Scaled(nn.Module):  # a stand-in for a learned demosaic: forward(raw, pattern)
        def __init__(self):
            super().__init__()
            self.gain = nn.Parameter(torch.tensor(2.0, dtype=torch.float64))

        def forward(self, raw, pattern):
            return self.gain * demosaic_bilinear(raw, pattern)

    net = Scaled()
    raw = _raw((1, 1, 8, 8))
    try:
        register_method("scaled_test", net)
        with pytest.raises(ValueError, match="already registered"):
            register_method("scaled_test", lambda r, p: r)
        torch.testing.assert_close(demosaic(raw, "RGGB", "scaled_test"), 2 * demosaic_bilinear(raw, "RGGB"))
    finally:
        METHODS.pop("scaled_test", None)
    stage = Demosaic(net, pattern="RGGB")
    assert "fn.gain" in stage.state_dict()
    stage(raw).sum().backward()
    assert net.gain.grad is not None and net.gain.grad.item() > 0


def test_lazy_method_is_imported_on_first_use(tmp_path, monkeypatch):
    (tmp_path / "lazy_demosaic_plugin.py").write_text(
        "from isettorch.isp import register_method, demosaic_nearest\n"
        "register_method('lazy_test', demosaic_nearest)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(demosaic_pkg._LAZY_METHODS, "lazy_test", "lazy_demosaic_plugin")
    monkeypatch.setitem(demosaic_pkg._LAZY_METHODS, "absent_test", "isettorch_no_such_module")
    try:
        assert get_method("lazy_test") is demosaic_nearest
    finally:
        METHODS.pop("lazy_test", None)
    with pytest.raises(ValueError, match="absent_test.*isettorch_no_such_module"):
        get_method("absent_test")


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_menon_without_refining_matches_colour_demosaicing(pattern):
    raw = _raw((1, 1, 17, 22), seed=13)
    expected = cd.demosaicing_CFA_Bayer_Menon2007(raw[0, 0].numpy(), pattern, refining_step=False)
    np.testing.assert_allclose(_to_np(demosaic(raw, pattern, "menon2007", refine=False)), expected, rtol=0, atol=1e-12)


def test_demosaic_module_by_name():
    raw = _raw((2, 1, 12, 12), seed=14)
    stage = Demosaic("malvar2004", pattern="BGGR")
    torch.testing.assert_close(stage(raw), demosaic_malvar2004(raw, "BGGR"), rtol=0, atol=0)
    torch.testing.assert_close(stage(raw, "GRBG"), demosaic_malvar2004(raw, "GRBG"), rtol=0, atol=0)
    assert "malvar2004" in repr(stage) and len(stage.state_dict()) == 0
    with pytest.raises(ValueError, match="method.*'no_such'"):
        Demosaic("no_such")


def test_one_entry_point_a_function_and_its_module():
    """``isettorch.isp.demosaic`` is a plain function and ``Demosaic`` the nn.Module over it (no callable
    module); the registry lives in the sub-package and is exported beside them."""
    import types

    import isettorch.isp as isp

    raw = _raw((1, 1, 8, 8), seed=15)
    assert isinstance(isp.demosaic, types.FunctionType) and isp.demosaic is demosaic_pkg.demosaic
    assert not callable(demosaic_pkg) and issubclass(isp.Demosaic, torch.nn.Module)
    assert isp.register_method is demosaic_pkg.register_method and isp.METHODS is demosaic_pkg.METHODS
    ref = demosaic_malvar2004(raw, "RGGB")
    torch.testing.assert_close(isp.demosaic(raw, "RGGB", "malvar2004"), ref, rtol=0, atol=0)
    torch.testing.assert_close(isp.Demosaic("malvar2004")(raw, "RGGB"), ref, rtol=0, atol=0)
    assert isp.BAYER_PATTERNS == ("RGGB", "BGGR", "GRBG", "GBRG")
    for p in isp.BAYER_PATTERNS:  # the one CFA table: the demosaic index map is the sensor CFA's
        from isettorch.sensor import CFA
        assert torch.equal(isp.bayer_index_map(p), CFA(p).index_map)


def test_gradients_after_a_call_in_inference_mode():
    # Masks are cached per size: ones first built under inference_mode must still work with autograd later.
    raw = _raw((1, 1, 14, 10), seed=16)
    with torch.inference_mode():
        for method in [*BUILTIN, "bilinear_colour"]:
            demosaic(raw, "BGGR", method)
        demosaic_generic(raw, torch.tensor([[0, 1], [2, 0]]), 3)
    x = raw.clone().requires_grad_(True)
    for method in [*BUILTIN, "bilinear_colour"]:
        demosaic(x, "BGGR", method).sum().backward()
    demosaic_generic(x, torch.tensor([[0, 1], [2, 0]]), 3).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


def test_unknown_method_error_names_every_method_including_learned():
    """Issue 18 friction 6: the registry's error lists the lazily registered ``learned`` method too."""
    from isettorch.isp.demosaicing import get_method

    with pytest.raises(ValueError, match="learned"):
        get_method("no_such_method")


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_malvar_green_is_the_mean_of_menons_directional_greens(pattern):
    # An identity between two independently written filters: at an R or B site, Malvar-He-Cutler's green kernel
    # (Fig. 2: 4 x centre + 2 x the four greens - the four same-colour samples two away, / 8) is the mean of Menon et
    # al.'s horizontal and vertical estimates h0 + h1 (bilinear green plus a quarter of the second difference of the
    # site's colour). Interior pixels (the two methods extend the border differently).
    from isettorch.isp.demosaicing._cfa import bayer_masks, correlate_hv
    from isettorch.isp.demosaicing.menon2007 import _H0, _H1

    raw = torch.rand(2, 1, 20, 24, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    g_mhc = demosaic(raw, pattern, method="malvar2004")[:, 1:2]
    (h0_h, h0_v), (h1_h, h1_v) = correlate_hv(raw, _H0, "mirror"), correlate_hv(raw, _H1, "mirror")
    mean_hv = ((h0_h + h1_h) + (h0_v + h1_v)) / 2
    m = bayer_masks(pattern, 20, 24, raw.device)
    at_rb = (m["R"] | m["B"]).expand_as(raw)[..., 2:-2, 2:-2]
    diff = (g_mhc - mean_hv)[..., 2:-2, 2:-2][at_rb]
    assert at_rb.sum() == 2 * 16 * 20 // 2
    assert float(diff.abs().max()) <= 1e-15


def test_malvar_keeps_the_mosaics_precision_under_autocast():
    # MHC is one convolution over the mosaic's polyphase planes; under bfloat16 autocast it still runs at the mosaic's
    # precision (as the elementwise methods do), and equals colour-demosaicing's kernels applied by hand in float64.
    raw = _raw((1, 1, 12, 14), seed=21, dtype=torch.float32)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under = demosaic_malvar2004(raw, "GRBG")
    assert under.dtype == torch.float32
    torch.testing.assert_close(under, demosaic_malvar2004(raw, "GRBG"), rtol=0, atol=0)
    expected = cd.demosaicing_CFA_Bayer_Malvar2004(raw[0, 0].double().numpy(), "GRBG")
    np.testing.assert_allclose(_to_np(under), expected, rtol=0, atol=2e-6)


def test_malvar_differentiates_after_a_first_call_in_inference_mode():
    # MHC's convolution weights are cached on first use; a first call in inference mode must not cache an inference
    # tensor, which autograd could not save in a later differentiated call (gradients checked by finite differences).
    import importlib

    importlib.import_module("isettorch.isp.demosaicing.linear")._malvar_polyphase.cache_clear()
    raw = _raw((1, 1, 8, 10), seed=22)
    with torch.inference_mode():
        demosaic_malvar2004(raw, "BGGR")
    assert torch.autograd.gradcheck(lambda r: demosaic_malvar2004(r, "BGGR"), (raw.clone().requires_grad_(True),),
                                    fast_mode=True)


@pytest.mark.parametrize("method", ["bilinear", "malvar2004", "menon2007"])
def test_a_mosaic_without_a_whole_cell_is_refused(method):
    # a 1 x 8 Bayer strip has no B (or no R) sample: every method refuses it alike
    with pytest.raises(ValueError, match="at least 2x2 pixels"):
        demosaic(torch.rand(1, 1, 1, 8), "RGGB", method=method)


def test_every_method_returns_an_empty_batch_and_the_learned_ones_refuse_a_3d_tensor():
    """Malvar raised on an empty batch where the others return (0, 3, H, W); the learned methods took [B, H, W], so
    an RGB image [3, H, W] given by mistake came back as three demosaicked mosaics."""
    from isettorch.isp.demosaicing import demosaic

    empty = torch.zeros(0, 1, 8, 10)
    for method in ("bilinear", "malvar2004", "menon2007", "learned_tiny"):
        assert demosaic(empty, "RGGB", method).shape == (0, 3, 8, 10)
    rgb = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0))
    for method in ("learned", "learned_small", "learned_tiny"):
        with pytest.raises(ValueError, match=r"raw: expected shape \[B, 1, H, W\]"):
            demosaic(rgb, "RGGB", method)
