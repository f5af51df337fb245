"""Gray-patch SNR of a Macbeth raw: the channel it measures is named, and an undefined SNR is None with the reason,
never inf or NaN."""

import math

import numpy as np
import pytest
import torch

from isettorch.isp.chart import gray_patch_snr, gray_patch_snr_db, snr_channel
from isettorch.sensor.cfa import CFA
from isettorch.sensor.raw import RawImage


def _raw(cfa: str, h: int, w: int, noise_std: float = 2.0, seed: int = 0) -> RawImage:
    # a chart whose bottom row (the gray patches) ramps from 600 DN (white) to 100 DN (black), black level 64
    g = torch.Generator().manual_seed(seed)
    cols = torch.arange(w, dtype=torch.float64)
    level = 600.0 - 500.0 * torch.floor(cols * 6 / w) / 5
    clean = (64.0 + level).expand(1, 1, h, w).clone()
    noisy = clean + noise_std * torch.randn(clean.shape, generator=g, dtype=torch.float64)
    return RawImage(noisy, "dn", CFA(cfa), black_level=64.0, white_level=1023.0, noise_free=clean)


@pytest.mark.parametrize("cfa,letter", [("RGGB", "G"), ("RGBW", "G"), ("YCMY", "Y"), ("RCCB", "W"), ("MONO", "W"),
                                        ("XTRANS", "G")])
def test_default_channel_is_g_else_the_most_frequent(cfa, letter):
    c = CFA(cfa)
    assert c.channel_names[snr_channel(c)] == letter


def test_snr_values_and_the_measured_channel():
    raw = _raw("RGBW", 96, 144)
    res = gray_patch_snr(raw)
    assert res["channel"] == "G"  # not R, which the argmax of RGBW's equal counts picked
    assert res["notes"] == [None] * 6 and all(n > 2 for n in res["pixels"])
    # patch 0 by hand: rows 3.25/4 .. 3.75/4 of the height, columns 0.25/6 .. 0.75/6 of the width, G pixels
    r, c = slice(int(3.25 * 96 / 4), int(3.75 * 96 / 4)), slice(int(0.25 * 144 / 6), int(0.75 * 144 / 6))
    m = raw.channel_masks()[1].bool()[r, c]
    sig = (raw.noise_free[0, 0, r, c] - 64.0)[m].mean()
    std = (raw.data - raw.noise_free)[0, 0, r, c][m].std()
    assert res["snr_db"][0] == pytest.approx(20 * math.log10(float(sig / std)), rel=1e-12)
    assert gray_patch_snr_db(raw, "R") == gray_patch_snr(raw, 0)["snr_db"]
    assert res["snr_db"][0] > res["snr_db"][-1]


def test_undefined_snr_is_none_with_a_reason():
    tiny = gray_patch_snr(_raw("RGBW", 8, 12))  # about one pixel of each channel per patch
    assert tiny["snr_db"] == [None] * 6 and tiny["pixels"] == [0] * 6  # (no inf, as before)
    for v, n, note in zip(tiny["snr_db"], tiny["pixels"], tiny["notes"]):
        assert (v is None) == (n < 2)
        if v is None:
            assert "a standard deviation needs at least 2" in note
    quiet = gray_patch_snr(_raw("RGGB", 96, 144, noise_std=0.0))  # a noise-free capture: std 0
    assert quiet["snr_db"] == [None] * 6 and all("no noise" in n for n in quiet["notes"])


def test_channel_argument_is_checked():
    raw = _raw("RGGB", 32, 48)
    with pytest.raises(ValueError, match=r"channel: the CFA has no channel 'W'"):
        gray_patch_snr(raw, "W")
    with pytest.raises(ValueError, match=r"channel: expected None, a CFA letter .* got 3"):
        gray_patch_snr(raw, 3)


def test_macbeth_delta_e_names_its_argument_and_a_black_white_patch():
    """A (23, 3) input was blamed on an internal 'reference'; a rendered white patch of Y = 0 gave 'xyz: expected
    finite values' (a 0 / 0 in the scaling to white)."""
    from isettorch.isp.chart import WHITE_PATCH, macbeth_delta_e

    with pytest.raises(ValueError, match=r"rendered_xyz: expected the 24 patches' XYZ"):
        macbeth_delta_e(torch.rand(23, 3, dtype=torch.float64))
    assert macbeth_delta_e(torch.rand(2, 3, 24, 3, dtype=torch.float64) + 0.1).delta_e.shape == (2, 3, 24)
    dark = torch.rand(24, 3, dtype=torch.float64)
    dark[WHITE_PATCH] = 0.0
    with pytest.raises(ValueError, match="rendered_xyz: scale_to_white needs a white patch"):
        macbeth_delta_e(dark)


def test_macbeth_delta_e_with_isetcams_white_patch_as_the_lab_white():
    """``lab_white='white_patch'`` is ISETCam ``macbethColorError``'s CIELAB white (the chart's ideal white patch at
    L* 100): equal to colour-science's CIEDE2000 with that white; the perfect white (the default) reads lower."""
    import colour

    from isettorch.isp.chart import WHITE_PATCH, macbeth_delta_e, macbeth_true_xyz

    ref = macbeth_true_xyz("D65").numpy()
    g = torch.Generator().manual_seed(1)
    rendered = torch.from_numpy(ref) * (1 + 0.1 * torch.rand(24, 3, generator=g, dtype=torch.float64))
    x = rendered.numpy() * (ref[WHITE_PATCH, 1] / rendered.numpy()[WHITE_PATCH, 1])
    white = ref[WHITE_PATCH]
    xy = colour.XYZ_to_xy(white)
    expected = colour.delta_E(colour.XYZ_to_Lab(x / white[1], xy), colour.XYZ_to_Lab(ref / white[1], xy),
                              method="CIE 2000")
    acc = macbeth_delta_e(rendered, "D65", lab_white="white_patch")
    np.testing.assert_allclose(acc.delta_e.numpy(), expected, rtol=1e-10, atol=1e-12)
    assert float(macbeth_delta_e(rendered, "D65").mean) < float(acc.mean)
    with pytest.raises(ValueError, match="lab_white: expected one of"):
        macbeth_delta_e(rendered, lab_white="isetcam")
