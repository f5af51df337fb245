"""The one sRGB encoding (isettorch.image.srgb_encode) and its clipping rule, used by the ISP, displays and
previews: against colour-science on [0, 1], and the rule outside it (below 0 -> 0; above 1 -> 1 with clip,
the same power law without)."""

import colour
import numpy as np
import pytest
import torch

from isettorch.image import srgb_decode, srgb_encode
from isettorch.isp import DisplayEncode
from isettorch.isp import srgb_encode as isp_srgb_encode
from isettorch.scene.display import srgb_eotf, srgb_inverse_eotf


def test_matches_colour_science_on_unit_interval():
    x = torch.linspace(0, 1, 1001, dtype=torch.float64)
    ref = colour.cctf_encoding(x.numpy(), "sRGB")
    np.testing.assert_allclose(srgb_encode(x).numpy(), ref, atol=1e-12)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)).numpy(), x.numpy(), atol=1e-12)
    np.testing.assert_allclose(srgb_decode(torch.from_numpy(ref)).numpy(), colour.cctf_decoding(ref, "sRGB"),
                               atol=1e-12)


def test_clipping_rule():
    x = torch.tensor([-1.0, -1e-3, 0.0, 1.0, 1.5, 4.0], dtype=torch.float64)
    clipped = srgb_encode(x)
    assert clipped[:3].tolist() == [0.0, 0.0, 0.0]
    white = 1.055 * 1.0 ** (1 / 2.4) - 0.055  # the curve at 1 (1 - 1e-16 in float64)
    assert clipped[3:].tolist() == [white] * 3
    open_top = srgb_encode(x, clip=False)
    assert open_top[:3].tolist() == [0.0, 0.0, 0.0]
    expect = 1.055 * x[3:] ** (1 / 2.4) - 0.055  # IEC 61966-2-1 curve continued above white
    torch.testing.assert_close(open_top[3:], expect, rtol=1e-15, atol=0)


@pytest.mark.parametrize("clip", [True, False])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_inplace_and_out_are_bitwise_the_same(clip, dtype):
    g = torch.Generator().manual_seed(0)
    x = (torch.rand(2, 3, 17, 19, generator=g, dtype=dtype) * 1.6 - 0.3)
    x[0, 0, 0, :4] = torch.tensor([0.0031308, 0.0, -0.0, 1.0], dtype=dtype)
    ref = srgb_encode(x, clip=clip)
    assert torch.equal(srgb_encode(x.clone(), clip=clip, inplace=True), ref)
    keep = x.clone()
    out = torch.empty_like(x)
    assert srgb_encode(x, clip=clip, out=out) is out and torch.equal(out, ref) and torch.equal(x, keep)


def test_every_caller_is_the_one_function():
    x = torch.linspace(-0.5, 2.0, 101, dtype=torch.float64)
    assert isp_srgb_encode is srgb_encode
    assert torch.equal(DisplayEncode("srgb", clip=True)(x), srgb_encode(x))
    assert torch.equal(DisplayEncode("srgb", clip=False)(x), srgb_encode(x, clip=False))
    assert torch.equal(srgb_inverse_eotf(x), srgb_encode(x, clip=False))
    assert torch.equal(srgb_eotf(x), srgb_decode(x))


@pytest.mark.parametrize("fn", [srgb_encode, srgb_decode])
def test_srgb_gradients_are_finite_at_black_the_knee_and_outside(fn):
    """The piecewise sRGB curves' derivatives (IEC 61966-2-1): encode 12.92 on the linear segment (at 0 too) and 0
    below 0 (clipped), decode 1 / 12.92 on its (unclipped) linear segment; the power segment's 1.055 / 2.4 at 1. A
    naive power law has NaN gradients at 0 and below (no other test looked at the gradient)."""
    x = torch.tensor([-0.1, 0.0, 0.0031308, 0.04045, 1.0, 1.5], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(fn(x).sum(), x)
    assert torch.isfinite(g).all(), g
    if fn is srgb_encode:
        assert float(g[0]) == 0.0 and float(g[1]) == pytest.approx(12.92)
        assert float(g[4]) == pytest.approx(1.055 / 2.4, rel=1e-12)
    else:  # decode has no clipping: its linear segment continues below 0
        assert float(g[0]) == pytest.approx(1 / 12.92) and float(g[1]) == pytest.approx(1 / 12.92)
    inner = torch.tensor([0.002, 0.2, 0.7], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(fn, (inner,))
