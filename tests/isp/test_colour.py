"""Colour stages: least-squares matrix fit, colorimetric recovery, white balance, display and encoding.

References: numpy.linalg.lstsq (independent solver), colour-science (CIE data, sRGB, dE2000),
ISETCam imageIlluminantCorrection (gray/white world formulas).
"""

import warnings

import colour
import numpy as np
import pytest
import torch

from isettorch import spectral
from isettorch.isp.colour import (
    DisplayEncode,
    IlluminantCorrection,
    SensorToXYZ,
    XYZToDisplay,
    apply_gains,
    apply_matrix,
    display_rgb_to_xyz_matrix,
    fit_colour_matrix,
    gray_world_gains,
    illuminant_gains,
    reflectance_set,
    sensor_responses,
    sensor_to_xyz_matrix,
    srgb_decode,
    srgb_encode,
    white_world_gains,
    white_xyz,
    xyz_responses,
)

W = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)


def _nikon_qe(w=W):
    cam = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    return spectral.resample(torch.tensor(cam.values.T.copy()), torch.tensor(cam.wavelengths), w)


def test_apply_matrix_matches_numpy_and_batched():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(2, 4, 3, 5, generator=g, dtype=torch.float64)
    m = torch.rand(3, 4, generator=g, dtype=torch.float64)
    ref = np.einsum("kc,bchw->bkhw", m.numpy(), img.numpy())
    np.testing.assert_allclose(apply_matrix(img, m).numpy(), ref, rtol=1e-12)
    mb = torch.stack([m, 2 * m])
    out = apply_matrix(img, mb)
    np.testing.assert_allclose(out[1].numpy(), 2 * ref[1], rtol=1e-12)
    with pytest.raises(ValueError, match="matrix"):
        apply_matrix(img, torch.eye(3))


def test_fit_matches_numpy_lstsq_on_random_and_on_macbeth():
    g = torch.Generator().manual_seed(1)
    src = torch.rand(30, 3, generator=g, dtype=torch.float64)
    tgt = torch.rand(30, 3, generator=g, dtype=torch.float64)
    ref = np.linalg.lstsq(src.numpy(), tgt.numpy(), rcond=None)[0].T  # ISETCam T = A \ B, M = T'
    np.testing.assert_allclose(fit_colour_matrix(src, tgt).numpy(), ref, rtol=1e-10, atol=1e-12)

    # The MCC-optimised Nikon matrix, with the responses computed independently in numpy.
    qe = _nikon_qe().numpy()
    refl = reflectance_set("macbeth", W).numpy()
    e = spectral.illuminant("D65", W, dtype=torch.float64).numpy()
    p = e * (W.numpy() * 1e-9) / (6.62607015e-34 * 299792458.0)
    cmf = spectral.cmfs(W, dtype=torch.float64).numpy()
    a = (refl * p * 10.0) @ qe.T
    b = 683.0 * (refl * e * 10.0) @ cmf.T
    ref = np.linalg.lstsq(a, b, rcond=None)[0].T
    np.testing.assert_allclose(sensor_to_xyz_matrix(_nikon_qe(), W).numpy(), ref, rtol=1e-8)


def test_colorimetric_sensor_recovers_xyz_exactly():
    # QE a linear combination of the photon-counting CMFs (cmf * hc / lambda, ISETCam XYZQuanta).
    mix = torch.tensor([[0.2, 0.7, 0.1], [0.05, 0.9, 0.05], [0.3, 0.1, 0.6]], dtype=torch.float64)
    qe = mix @ (spectral.cmfs(W, dtype=torch.float64) / W) * 50
    m = sensor_to_xyz_matrix(qe, W)  # fitted on the Macbeth chart under D65
    # ... and tested on 190 other surfaces under illuminant A.
    s = sensor_responses(qe, W, "A", "rawtoaces190")
    x = xyz_responses(W, "A", "rawtoaces190")
    np.testing.assert_allclose((s @ m.T).numpy(), x.numpy(), rtol=1e-9, atol=1e-9 * x.abs().max().item())


def test_xyz_responses_match_colour_science():
    refl = reflectance_set("macbeth", W)[:3]
    x = xyz_responses(W, "D65", refl)
    x = x / xyz_responses(W, "D65", torch.ones(1, W.numel(), dtype=torch.float64))[0, 1]
    shape = colour.SpectralShape(400, 700, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    for i in range(3):
        sd = colour.SpectralDistribution(dict(zip(W.tolist(), refl[i].tolist())))
        ref = colour.sd_to_XYZ(sd, cmfs, ill, method="Integration") / 100
        np.testing.assert_allclose(x[i].numpy(), ref, rtol=2e-3)


def test_nikon_mcc_optimised_delta_e_below_2():
    qe = _nikon_qe()
    m = sensor_to_xyz_matrix(qe, W)
    est = sensor_responses(qe, W, "D65") @ m.T
    true = xyz_responses(W, "D65")
    white = xyz_responses(W, "D65", torch.ones(1, W.numel(), dtype=torch.float64))[0]
    xy_w = colour.XYZ_to_xy(white.numpy())
    de = colour.delta_E(colour.XYZ_to_Lab(est.numpy() / white[1].item(), xy_w),
                        colour.XYZ_to_Lab(true.numpy() / white[1].item(), xy_w), method="CIE 2000")
    assert de.mean() < 2.0, de.mean()


def test_gray_world_gains_follow_isetcam_formula():
    g = torch.Generator().manual_seed(2)
    img = torch.rand(2, 3, 6, 7, generator=g, dtype=torch.float64) + 0.05
    white = torch.tensor([0.95, 1.0, 1.09], dtype=torch.float64)
    gains = gray_world_gains(img, white)
    avg = img.mean((-2, -1))
    ref = (white / white[0]) * (avg[:, :1] / avg)  # ISETCam grayWorld: D = whiteRatio .* avg(1) ./ avg
    np.testing.assert_allclose(gains.numpy(), ref.numpy(), rtol=1e-12)
    out_mean = apply_gains(img, gains).mean((-2, -1))
    np.testing.assert_allclose((out_mean / out_mean[:, :1]).numpy(), (white / white[0]).expand(2, 3).numpy(),
                               rtol=1e-12)


def test_a_black_image_is_balanced_by_the_whites_gains():
    """An image black in every channel has nothing to balance: gray and white world give it the white's own gains
    (its output stays black), and the other items of its batch keep their own gains. A black or very dim scene
    through the gray-world cameras (imx363, paper2004_cds, phone_microlens) raised, failing the whole batch."""
    g = torch.Generator().manual_seed(4)
    img = torch.rand(2, 3, 6, 7, generator=g, dtype=torch.float64) + 0.05
    white = torch.tensor([0.95, 1.0, 1.09], dtype=torch.float64)
    batch = img.clone()
    batch[1] = 0
    for fn in (gray_world_gains, white_world_gains):
        gains = fn(batch, white)
        np.testing.assert_allclose(gains[0].numpy(), fn(img[:1], white)[0].numpy(), rtol=1e-12)
        np.testing.assert_allclose(gains[1].numpy(), (white / white[0]).numpy(), rtol=1e-12)
    partly = img[:1].clone()
    partly[0, 2] = 0  # one channel without signal (a single-hue image): no gray-world gain exists
    with pytest.raises(ValueError, match="img: every channel needs a finite, positive mean"):
        gray_world_gains(partly)
    from isettorch.camera import Camera
    from isettorch.scene import Scene

    cam = Camera.from_config("paper2004_cds")
    cam.noise = False
    out = cam(Scene(torch.zeros(1, 31, 24, 32, dtype=torch.float64), torch.arange(400.0, 701.0, 10.0), hfov_deg=1.0))
    assert torch.equal(out, torch.zeros_like(out))


def test_an_item_without_signal_in_a_channel_keeps_the_whites_gains_in_the_isp():
    """A dim noisy frame's channel means above black are noise of either sign: gray world has no gains for it. The
    ISP's correction gives that item the white's own gains with a warning, and the batch's other items their own
    (the imx363 and phone_microlens cameras raised on 9 of 10 seeds of a 1e-3 cd/m^2 chart at 1 ms); a direct call
    still refuses it unless asked."""
    g = torch.Generator().manual_seed(5)
    img = torch.rand(2, 3, 6, 7, generator=g, dtype=torch.float64) + 0.05
    img[1] = 1e-5 * torch.randn(3, 6, 7, generator=g, dtype=torch.float64)
    img[1, 0] -= 1e-4  # the first channel's mean is negative
    white = torch.tensor([0.95, 1.0, 1.09], dtype=torch.float64)
    for method in ("gray_world", "white_world"):
        with pytest.raises(ValueError, match="every channel needs a finite, positive mean"):
            illuminant_gains(img, method, white)
        ic = IlluminantCorrection(method, space="sensor")
        with pytest.warns(UserWarning, match=r"white balance: item\(s\) \[1\] have a channel whose mean is <= 0"):
            out = ic(img, white=white)
        own = illuminant_gains(img[:1], method, white)
        np.testing.assert_allclose(ic.last_gains[0].numpy(), own[0].numpy(), rtol=1e-12)
        np.testing.assert_allclose(ic.last_gains[1].numpy(), (white / white[0]).numpy(), rtol=1e-12)
        torch.testing.assert_close(out[1], img[1] * (white / white[0])[:, None, None], rtol=1e-12, atol=0)
        with pytest.warns(UserWarning):
            direct = illuminant_gains(img, method, white, no_signal="white")
        torch.testing.assert_close(direct, ic.last_gains, rtol=0, atol=0)
    with pytest.raises(ValueError, match="no_signal: expected one of"):
        gray_world_gains(img, no_signal="clip")
    # a tiny positive mean is no signal either: a demosaic's leak of 1.8e-5 into a black red channel (the imx363
    # camera, menon2007) gave gains [1, 1.8e-5, 1.8e-5] and crushed the image to black without a word, where an
    # exact 0 was refused; a single-hue image's 1e-3 still balances (gain 1e3)
    for r, balanced in ((1e-5, False), (-1e-5, False), (0.0, False), (1e-3, True)):
        flat = torch.full((1, 3, 4, 4), 0.5, dtype=torch.float64)
        flat[:, 0] = r
        ic = IlluminantCorrection("gray_world", space="sensor")
        if balanced:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                out = ic(flat, white=torch.ones(3, dtype=torch.float64))
            np.testing.assert_allclose(out.mean((-2, -1))[0].numpy(), r, rtol=1e-12)
        else:
            with pytest.warns(UserWarning, match=r"a channel whose mean is <= 0 or at most 0.0001 of the largest"):
                out = ic(flat, white=torch.ones(3, dtype=torch.float64))
            torch.testing.assert_close(out, flat, rtol=0, atol=0)  # the white's own gains: 1, 1, 1
            with pytest.raises(ValueError, match=r"above 0.0001 of the largest channel's"):
                gray_world_gains(flat)


def test_white_world_uses_bright_pixels_of_brightest_plane():
    img = torch.zeros(1, 3, 1, 4, dtype=torch.float64)
    img[0, :, 0] = torch.tensor([[1.0, 0.8, 0.1, 0.2], [0.5, 0.4, 0.2, 0.1], [0.25, 0.2, 0.9, 0.05]]).T.T
    # channel 0 has the highest max (1.0); bright pixels: channel-0 value >= 0.7 -> columns 0 and 1
    gains = white_world_gains(img)
    brt = img[0, :, 0, :2].mean(-1)
    np.testing.assert_allclose(gains[0].numpy(), (brt[0] / brt).numpy(), rtol=1e-12)


def test_white_world_under_a_coloured_light_takes_a_saturated_surface_as_documented():
    """The documented limit of ISETCam's rule: the Macbeth chart under illuminant A in XYZ selects the yellow patch
    (15) beside the white (18), so the white renders blue, b* about -30 (colour-science's Lab)."""
    from isettorch.metrics import macbeth_reference_xyz

    ref = macbeth_reference_xyz("A")[0].double()
    img = (ref / ref[18, 1]).T.reshape(1, 3, 1, 24)
    d65 = white_xyz("D65").double()
    gains = white_world_gains(img, d65, reference_channel=1)
    flat = img.flatten(2)[0]
    assert (flat[0] >= 0.7 * flat.amax()).nonzero().flatten().tolist() == [15, 18]
    bright = flat[:, [15, 18]].mean(-1)  # the rule by hand: the bright pixels' mean mapped to the white, Y gain 1
    expect = (d65 / bright) / (d65[1] / bright[1])
    np.testing.assert_allclose(gains[0].numpy(), expect.numpy(), rtol=1e-12)
    np.testing.assert_allclose(gains[0].numpy(), [0.84, 1.0, 4.84], atol=0.01)
    lab = colour.XYZ_to_Lab((flat[:, 18] * gains[0]).numpy(), colour.XYZ_to_xy(d65.numpy()))
    assert lab[2] == pytest.approx(-30.4, abs=0.1)


def test_illuminant_gains_methods_and_errors():
    img = torch.rand(1, 3, 4, 4, dtype=torch.float64) + 0.1
    assert torch.equal(illuminant_gains(img, "none"), torch.ones(1, 3, dtype=torch.float64))
    man = illuminant_gains(img, "manual", gains=[1.0, 2.0, 3.0])
    assert man.tolist() == [[1.0, 2.0, 3.0]]
    with pytest.raises(ValueError, match="method"):
        illuminant_gains(img, "grey_wrld")
    with pytest.raises(ValueError, match="gains"):
        illuminant_gains(img, "manual")
    with pytest.raises(ValueError, match="positive mean"):
        gray_world_gains(torch.zeros(1, 3, 2, 2).index_fill(1, torch.tensor([0]), 1.0))  # G and B black
    with pytest.raises(ValueError, match="space"):
        IlluminantCorrection("gray_world", space="lab")


def test_srgb_encoding_matches_colour_science():
    x = torch.linspace(0, 1, 101, dtype=torch.float64)
    np.testing.assert_allclose(srgb_encode(x).numpy(), colour.cctf_encoding(x.numpy(), "sRGB"), atol=1e-12)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)).numpy(), x.numpy(), atol=1e-12)
    enc = DisplayEncode("srgb")(torch.tensor([-0.5, 0.5, 2.0], dtype=torch.float64))
    assert enc[0] == 0 and enc[2].item() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(DisplayEncode(2.2)(torch.tensor([0.5], dtype=torch.float64)).numpy(), 0.5 ** (1 / 2.2))


def test_gamma_encoding_without_clipping_keeps_headroom_and_encodes_zero_and_below_as_zero():
    """clip=False: above white follows the curve (2 ** (1 / 2.2)); 0 and negatives encode as 0 as in srgb_encode (the
    gamma path gave 5.7e-18 in float32, the power of the smallest normal number), with a finite gradient."""
    x = torch.tensor([-0.2, -0.01, 0.0, 0.25, 2.0], requires_grad=True)
    enc = DisplayEncode(2.2, clip=False)(x)
    assert enc[:3].tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(enc[3:].detach().numpy(), np.array([0.25, 2.0]) ** (1 / 2.2), rtol=1e-6)
    (g,) = torch.autograd.grad(enc.sum(), x)
    assert bool(torch.isfinite(g).all()) and g[:3].tolist() == [0.0, 0.0, 0.0]


def test_srgb_display_matrix_and_white():
    d = XYZToDisplay("srgb")
    ref = colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB
    # colour-science uses the standard's 4-decimal matrix; ours is derived from the primaries (4e-4 apart).
    np.testing.assert_allclose(d.matrix.numpy(), ref, atol=5e-4)
    d65 = white_xyz("D65")
    np.testing.assert_allclose(apply_matrix(d65.reshape(1, 3, 1, 1).float(), d.matrix).flatten().numpy(),
                               [1.0, 1.0, 1.0], atol=2e-3)


def test_display_from_primary_spds():
    # Gaussian primaries; the matrix columns are the primaries' XYZ (colour-science, k = 683).
    lam = W
    spd = torch.stack([torch.exp(-0.5 * ((lam - c) / 20) ** 2) for c in (610.0, 540.0, 460.0)]) * 1e-3
    rgb2xyz = display_rgb_to_xyz_matrix(spd, W)
    shape = colour.SpectralShape(400, 700, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    for i in range(3):
        sd = colour.SpectralDistribution(dict(zip(W.tolist(), spd[i].tolist())))
        ref = colour.sd_to_XYZ(sd, cmfs, k=683, method="Integration")
        np.testing.assert_allclose(rgb2xyz[:, i].numpy(), ref, rtol=1e-6)

    class _Display:
        name = "gauss"
        wavelengths_nm = W
        primaries_spd = spd

    d = XYZToDisplay(_Display())
    assert d.max_luminance_cd_m2 == pytest.approx(rgb2xyz[1].sum().item())
    white = d.white_point_xyz.double().reshape(1, 3, 1, 1)
    np.testing.assert_allclose(d(white).flatten().numpy(), [1, 1, 1], atol=1e-5)


def test_sensor_to_xyz_module_normalised_white_and_gradients():
    qe = _nikon_qe()
    s2x = SensorToXYZ().fit(qe, W)
    white = s2x.sensor_white
    assert white.max().item() == pytest.approx(1.0)
    y = apply_matrix(white.reshape(1, -1, 1, 1), s2x.matrix)[0, 1, 0, 0]
    assert y.item() == pytest.approx(1.0, rel=1e-10)
    # Chromaticity of the white matches D65's (within the fit's residual).
    xyz_w = apply_matrix(white.reshape(1, -1, 1, 1), s2x.matrix).flatten().numpy()
    np.testing.assert_allclose(colour.XYZ_to_xy(xyz_w), colour.XYZ_to_xy(white_xyz("D65").numpy()), atol=5e-3)
    learn = SensorToXYZ(learnable=True).fit(qe, W)
    img = torch.rand(1, 3, 2, 2, dtype=torch.float64)
    learn(img).sum().backward()
    assert learn.matrix.grad is not None and learn.matrix.grad.abs().sum() > 0
    src = torch.rand(10, 3, dtype=torch.float64, requires_grad=True)
    tgt = torch.rand(10, 3, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda s: fit_colour_matrix(s, tgt), (src,))


def test_a_loaded_fitted_matrix_keeps_following_the_qe_and_a_given_one_stays():
    """A checkpoint's matrix loaded into a fresh module: a fitted one refits when the QE changes, as the module it
    came from does (it was taken as given and froze: a resumed run with learnable filters drifted from the
    uninterrupted one); a given one (set_matrix) stays given."""
    qe = _nikon_qe()
    other = qe * torch.linspace(0.5, 1.5, W.numel(), dtype=torch.float64)  # the filters after a step
    fitted = SensorToXYZ().fit(qe, W)
    loaded = SensorToXYZ()
    loaded.load_state_dict(fitted.state_dict())
    assert torch.equal(loaded.fit(qe, W).matrix, fitted.matrix)
    torch.testing.assert_close(loaded.fit(other, W).matrix, SensorToXYZ().fit(other, W).matrix, rtol=1e-12, atol=0)
    # a training run's resume: the checkpoint's matrix is the QE's before the last filter step
    resumed = SensorToXYZ()
    resumed.load_state_dict(fitted.state_dict())
    torch.testing.assert_close(resumed.fit(other, W).matrix, SensorToXYZ().fit(other, W).matrix, rtol=1e-12, atol=0)
    # a checkpoint from before the module said whether its matrix was fitted: the next fit tells
    old = {k: v for k, v in fitted.state_dict().items() if k != "fitted"}
    legacy = SensorToXYZ()
    legacy.load_state_dict(old)
    assert torch.equal(legacy.fit(qe, W).matrix, fitted.matrix)
    torch.testing.assert_close(legacy.fit(other, W).matrix, SensorToXYZ().fit(other, W).matrix, rtol=1e-12, atol=0)
    # the same through a graph fit (learnable filters, grad enabled: refitted every call)
    q = other.clone().requires_grad_(True)
    graph = SensorToXYZ()
    graph.load_state_dict(fitted.state_dict())
    graph.fit(qe, W)
    m = graph.fit(q, W).matrix
    assert m.requires_grad
    torch.testing.assert_close(m.detach(), SensorToXYZ().fit(other, W).matrix, rtol=1e-12, atol=0)
    given = torch.eye(3, dtype=torch.float64) * 0.5
    kept = SensorToXYZ()
    kept.load_state_dict(SensorToXYZ(matrix=given).state_dict() | {"sensor_white": torch.ones(3)}, strict=False)
    assert torch.equal(kept.fit(qe, W).matrix, given) and torch.equal(kept.fit(other, W).matrix, given)
    # an old checkpoint of a given matrix loaded into a module that had fitted, saved before its next fit: still given
    before = SensorToXYZ().fit(qe, W)
    before.load_state_dict({k: v for k, v in SensorToXYZ(matrix=given).state_dict().items() if k != "fitted"}
                           | {"sensor_white": torch.ones(3)})
    after = SensorToXYZ()
    after.load_state_dict(before.state_dict())
    assert torch.equal(after.fit(other, W).matrix, given)
    refitted = SensorToXYZ().fit(qe, W)  # a module that had fitted, loading a given matrix, keeps it
    refitted.load_state_dict(SensorToXYZ(matrix=given).state_dict() | {"sensor_white": torch.ones(3)}, strict=False)
    assert torch.equal(refitted.fit(qe, W).matrix, given)


def test_bradford_adaptation_matches_colour_science_and_whitens_display():
    from isettorch.isp.colour import bradford_matrix

    a, b = white_xyz("D65"), white_xyz("A")
    ref = colour.adaptation.matrix_chromatic_adaptation_VonKries(a.numpy(), b.numpy(), transform="Bradford")
    np.testing.assert_allclose(bradford_matrix(a, b).numpy(), ref, atol=1e-12)
    d65 = white_xyz("D65").reshape(1, 3, 1, 1)
    adapted = XYZToDisplay("apple", adapt_from="D65").double()
    np.testing.assert_allclose(adapted(d65).flatten().numpy(), [1, 1, 1], atol=1e-6)
    plain = XYZToDisplay("apple").double()  # the Apple display's white is not D65: D65 renders tinted
    assert (plain(d65).flatten() - 1).abs().max() > 0.05


@pytest.mark.parametrize("illuminant", ["D65", "A", "F2", "F11"])
def test_macbeth_delta_e_of_the_true_chart_is_zero(illuminant):
    """The true chart scored against itself is dE 0 under any illuminant: its CIELAB white is integrated on the
    chart's own grid (a white on another grid put F2's white patch 0.028 off white, which raised)."""
    from isettorch.isp.chart import macbeth_delta_e, macbeth_true_xyz

    acc = macbeth_delta_e(macbeth_true_xyz(illuminant), illuminant)
    assert float(acc.max) < 1e-9


def test_macbeth_true_xyz_against_colour_science():
    """The chart's true XYZ (the reference every chart dE is scored against) under A, F2 and F11, from colour-science:
    the BabelColor average reflectances, the CIE 1931 observer and the CIE illuminant integrated over 400-700 nm.
    Under A (smooth) on the chart's 10 nm grid they agree to rounding. F2's and F11's mercury lines fall between 10 nm
    samples: the library band-averages the lamps onto its grid, against colour-science integrating them on their own
    5 nm table, within dE2000 0.7 on every patch (point-sampling the lamps at 10 nm is 9-11 off)."""
    from isettorch.isp.chart import macbeth_true_xyz

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    patches = list(colour.SDS_COLOURCHECKERS["BabelColor Average"].values())

    def reference(name, step):
        shape = colour.SpectralShape(400, 700, step)
        c, ill = cmfs.copy().align(shape), colour.SDS_ILLUMINANTS[name].copy().align(shape)
        return np.stack([colour.sd_to_XYZ(p.copy().align(shape), c, ill, method="Integration") / 100 for p in patches])

    np.testing.assert_allclose(macbeth_true_xyz("A").numpy(), reference("A", 10), rtol=0, atol=1e-12)
    for ours_name, name in (("F2", "FL2"), ("F11", "FL11")):
        ref = reference(name, 5)
        white = colour.XYZ_to_xy(ref[18])
        de = colour.delta_E(colour.XYZ_to_Lab(macbeth_true_xyz(ours_name).numpy(), white),
                            colour.XYZ_to_Lab(ref, white), method="CIE 2000")
        assert de.max() < 0.75, (ours_name, de.max())


def test_colour_stages_refuse_bad_input_naming_it():
    """NaN, zero, singular or out-of-range inputs to the colour stages are a ValueError naming the argument (an ISP
    audit found them returning NaN, a minimum-norm matrix or a RuntimeError)."""
    from isettorch.image import bradford_matrix
    from isettorch.isp import ImageProcessor
    from isettorch.isp.chart import patch_means
    from isettorch.isp.colour import (
        DisplayEncode,
        XYZToDisplay,
        fit_colour_matrix,
        gray_world_gains,
        illuminant_gains,
        white_xyz,
    )

    img = torch.rand(2, 3, 8, 8, dtype=torch.float64) + 0.1
    with pytest.raises(ValueError, match="white: expected positive, finite"):
        gray_world_gains(img, white=[1.0, float("nan"), 1.0])
    with pytest.raises(ValueError, match="reference_channel: expected a channel index in 0..2"):
        gray_world_gains(img, reference_channel=5)
    with pytest.raises(ValueError, match="gains: expected finite"):
        illuminant_gains(img, "manual", gains=[1.0, float("nan"), 1.0])
    with pytest.raises(ValueError, match="gains: expected positive"):
        illuminant_gains(img, "manual", gains=[1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="source_white: expected a white with positive luminance"):
        bradford_matrix(torch.zeros(3), torch.tensor([0.95, 1.0, 1.09]))
    with pytest.raises(ValueError, match="adapt_from: expected an illuminant name or a white's XYZ"):
        XYZToDisplay(adapt_from=torch.tensor([1.0, 1.0]))
    with pytest.raises(ValueError, match="illuminant: expected a spectrum with luminance"):
        white_xyz(torch.zeros(81))
    src = torch.rand(24, 2, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"source: its 3 channels are linearly dependent .*rank 2"):
        fit_colour_matrix(torch.cat([src, src[:, :1]], dim=1), torch.rand(24, 3, dtype=torch.float64))
    # nearly dependent (a third channel 1e-8 off the first): determined, but the matrix's opposed coefficients of
    # ~1e7 amplify any error in the sensor values; it was fitted without a word. A condition number of 4e2 is fine.
    g = torch.Generator().manual_seed(1)
    near = torch.cat([src, src[:, :1] + 1e-8 * torch.rand(24, 1, generator=g, dtype=torch.float64)], dim=1)
    with pytest.warns(UserWarning, match=r"source: the colour fit is ill-conditioned \(condition number [0-9.e+]+ of "
                                         r"the source's 3 channels over 24 samples"):
        m = fit_colour_matrix(near, torch.rand(24, 3, generator=g, dtype=torch.float64))
    assert float(m.abs().max()) > 1e5  # what the warning is about
    ok = torch.cat([src, src[:, :1] + 2e-3 * torch.rand(24, 1, generator=g, dtype=torch.float64)], dim=1)
    assert 1e2 < float(torch.linalg.cond(ok / ok.amax(0))) < 1e5
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit_colour_matrix(ok, torch.rand(24, 3, generator=g, dtype=torch.float64))
    for bad in (True, float("inf"), -2.0):
        with pytest.raises(ValueError, match="encoding: expected"):
            DisplayEncode(bad)
    assert DisplayEncode("sRGB").encoding == "srgb"
    with pytest.raises(ValueError, match="grid: expected 1 <= rows"):
        patch_means(img, grid=(0, 6))
    with pytest.raises(ValueError, match="grid: expected 1 <= rows <= 8"):
        patch_means(img, grid=(4, 60))
    ip = ImageProcessor(sensor_to_xyz=torch.eye(3))
    bad = img.clone()
    bad[1, 2, 3, 4] = float("nan")
    with pytest.raises(ValueError, match="sensor: expected finite values, found 1"):
        ip.from_demosaiced(bad)


def test_white_preserving_fit_is_the_constrained_least_squares():
    """fit_colour_matrix(..., white=(w_s, w_t)) is the least-squares matrix with M w_s = w_t exactly: numpy's
    solution of the KKT system [[G, w_s], [w_s^T, 0]] per output (Finlayson & Drew 1997), never a smaller residual
    than the unconstrained fit."""
    from isettorch.isp.colour import fit_colour_matrix

    g = np.random.default_rng(3)
    a, b = g.uniform(0.05, 1, (24, 3)), g.uniform(0.05, 1, (24, 3))
    ws, wt = g.uniform(0.5, 1, 3), np.array([0.9505, 1.0, 1.089])
    m = fit_colour_matrix(torch.tensor(a), torch.tensor(b), white=(torch.tensor(ws), torch.tensor(wt))).numpy()
    np.testing.assert_allclose(m @ ws, wt, rtol=0, atol=1e-12)
    kkt = np.block([[a.T @ a, ws[:, None]], [ws[None, :], np.zeros((1, 1))]])
    ref = np.linalg.solve(kkt, np.vstack([a.T @ b, wt[None, :]]))[:3].T
    np.testing.assert_allclose(m, ref, rtol=1e-9, atol=1e-12)
    free = fit_colour_matrix(torch.tensor(a), torch.tensor(b)).numpy()
    assert np.linalg.norm(a @ m.T - b) >= np.linalg.norm(a @ free.T - b)
    with pytest.raises(ValueError, match="white: expected a source white of 3 and a target white of 3"):
        fit_colour_matrix(torch.tensor(a), torch.tensor(b), white=(torch.ones(2), torch.ones(3)))


def test_camera_white_preserving_conversion_renders_the_white_neutral():
    """isp.sensor_conversion.white_preserving: the default camera's perfect white under D65 maps to the D65 white of
    its own grid (ISETCam's free fit puts it at a* = -3.5), and the Macbeth chart's neutrals get closer (noise off,
    mean dE2000 of the six neutrals 1.7 -> under 1)."""
    import warnings

    import isettorch
    from isettorch.isp.chart import macbeth_delta_e, patch_means
    from isettorch.isp.colour import white_xyz
    from isettorch.scene import macbeth

    out = {}
    for wp in (False, True):
        cfg = isettorch.camera.load_config("default")
        cfg.setdefault("isp", {}).setdefault("sensor_conversion", {})["white_preserving"] = wp
        cam = isettorch.Camera.from_config(cfg)
        cam.noise = False
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = cam(macbeth("D65", patch_size=16), return_intermediates=True)
        s2x = cam.isp.sensor_to_xyz
        white = (s2x.matrix.double() @ s2x.sensor_white.double())
        out[wp] = (white / white[1], macbeth_delta_e(patch_means(res.isp.xyz).double(), "D65").delta_e.reshape(-1))
    grid_white = white_xyz("D65", torch.arange(400.0, 701.0, 10.0, dtype=torch.float64))
    torch.testing.assert_close(out[True][0], grid_white, rtol=0, atol=1e-9)
    assert float((out[False][0] - grid_white).abs().max()) > 0.015  # X 0.931 against 0.949
    assert float(out[True][1][18:].mean()) < 1.0 < float(out[False][1][18:].mean())


def test_colour_helpers_refuse_integer_images_and_bad_matrices_gains_and_means():
    """Each was a silent wrong number: an int image cast a 0.5 matrix to 0 (all zeros); a NaN matrix or gain, a
    negative gain passed; a NaN or Inf pixel gave NaN gray/white-world gains; 8-bit codes were encoded as linear
    values (128 -> 1.0) or decoded to 524,947."""
    from isettorch.image import srgb_decode, srgb_encode
    from isettorch.isp.colour import apply_gains, apply_matrix, gray_world_gains, white_world_gains

    img = torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    torch.testing.assert_close(apply_matrix(img, [[0.5, 0, 0], [0, 1, 0], [0, 0, 2]]),
                               img * torch.tensor([0.5, 1, 2], dtype=torch.float64).view(1, 3, 1, 1))
    cases = ((lambda: apply_matrix((img * 255).long(), torch.eye(3) * 0.5), TypeError, "img: expected a floating"),
             (lambda: apply_matrix(img, torch.full((3, 3), float("nan"))), ValueError, "matrix: expected finite"),
             (lambda: apply_gains(img, [-1.0, 1.0, 1.0]), ValueError, "gains: expected positive"),
             (lambda: apply_gains(img, [float("nan"), 1.0, 1.0]), ValueError, "gains: expected finite"),
             (lambda: gray_world_gains(img * float("nan")), ValueError, "finite, positive mean"),
             (lambda: white_world_gains(img.index_fill(2, torch.tensor([0]), float("inf"))), ValueError,
              "finite, positive mean"),
             (lambda: srgb_encode(torch.tensor([0, 128, 255], dtype=torch.uint8)), TypeError, "linear: expected"),
             (lambda: srgb_decode(torch.tensor([0, 128, 255], dtype=torch.uint8)), TypeError, "encoded: expected"))
    for call, error, message in cases:
        with pytest.raises(error, match=message):
            call()


def test_colour_stage_arguments_are_checked_where_given():
    """Bad input named where it is given (an audit of the ISP): reflectances of the wrong length (a bare broadcasting
    error) or NaN (a NaN matrix reported later as 'source'); a manual (B, C) gains flattened to (B C,) at
    construction, and a batch that does not match the image (a bare expand error); a white-world criterion
    outside (0, 1] accepted until the first forward; adapt_from with a misspelled illuminant or a negative XYZ (the
    error named cct_k or source_white)."""
    from isettorch.isp.colour import (
        IlluminantCorrection,
        XYZToDisplay,
        illuminant_gains,
        sensor_responses,
        xyz_responses,
    )

    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    qe = torch.rand(3, 31, dtype=torch.float64)
    for bad, match in ((torch.rand(5, 30), r"reflectances: expected \(N, 31\)"),
                       (torch.full((2, 31), float("nan")), "reflectances")):
        with pytest.raises(ValueError, match=match):
            sensor_responses(qe, w, "D65", bad)
        with pytest.raises(ValueError, match=match):
            xyz_responses(w, "D65", bad)
    ic = IlluminantCorrection("manual", gains=torch.tensor([[1.0, 2.0, 3.0], [1.0, 1.0, 1.0]]))
    img = torch.ones(2, 3, 4, 4)
    out = ic(img)
    assert torch.equal(out[0, :, 0, 0], torch.tensor([1.0, 2.0, 3.0])) and torch.equal(out[1], img[1])
    with pytest.raises(ValueError, match=r"gains: expected \(3,\) or \(3, 3\) for the image's 3 items"):
        illuminant_gains(torch.ones(3, 3, 4, 4), "manual", gains=torch.ones(2, 3))
    with pytest.raises(ValueError, match="criterion: expected a fraction in"):
        IlluminantCorrection("white_world", criterion=5)
    with pytest.raises(ValueError, match="adapt_from"):
        XYZToDisplay("srgb", adapt_from="D66")
    with pytest.raises(ValueError, match="adapt_from: expected an illuminant name or a white's XYZ"):
        XYZToDisplay("srgb", adapt_from=[1.0, -1.0, 1.0])


@pytest.mark.parametrize("setting, value", [("illuminant", "A"), ("white_preserving", True), ("normalize", False),
                                            ("observer", "1964")])
def test_a_changed_fit_setting_refits_the_matrix(setting, value):
    # The fit's cache was keyed by the QE and grid only: after s.illuminant = 'A' a fit of the same QE returned the
    # D65 matrix (0.33 from the fit under A). Each setting now refits: the matrix is a fresh module's.
    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    qe = spectral.cmfs(w, dtype=torch.float64) / w * 300 + 0.05 * torch.rand(3, w.numel(), dtype=torch.float64,
                                                                             generator=torch.Generator().manual_seed(1))
    s = SensorToXYZ().fit(qe, w)
    setattr(s, setting, value)
    fresh = SensorToXYZ(**{setting: value}).fit(qe, w)
    assert not torch.allclose(fresh.matrix, SensorToXYZ().fit(qe, w).matrix, rtol=1e-3, atol=0)
    torch.testing.assert_close(s.fit(qe, w).matrix, fresh.matrix, rtol=1e-12, atol=0)


def test_rawtoaces_reflectances_hold_their_end_values_beyond_their_data():
    """The 190 training reflectances (380-780 nm) dropped to 0 beyond 780 nm (resample's 0 outside), so a
    near-infrared-sensitive sensor fitted on 380-830 nm saw black surfaces there while the Macbeth set held its end
    values. Now both hold them, as colour-science's default constant extrapolation does (CIE 015:2018 7.2.2)."""
    from colour import SpectralShape
    from colour.characterisation import read_training_data_rawtoaces_v1

    from isettorch.isp.colour import reflectance_set

    w = torch.arange(380.0, 831.0, 5.0, dtype=torch.float64)
    ours = reflectance_set("rawtoaces190", w)
    ref = read_training_data_rawtoaces_v1().copy().align(SpectralShape(380, 830, 5))  # Constant extrapolator
    np.testing.assert_allclose(ours.numpy(), np.asarray(ref.values).T, atol=1e-12)
    beyond = ours[:, w > 780]
    assert torch.equal(beyond, ours[:, w == 780].expand_as(beyond)) and float(ours[:, w == 780].max()) > 0.5
    both = reflectance_set("macbeth+rawtoaces190", w)
    torch.testing.assert_close(both[24:], ours)


def test_scene_window_is_the_charts_footprint_and_checks_its_pitch():
    """The chart's footprint d tan(fov / 2) / pitch either side of the centre. A negative pitch had given the inverted
    window (317, 83, 475, 125) silently, 0 a bare ZeroDivisionError, NaN a float-to-int error; patch_means's
    fraction as a tensor a TypeError from round()."""
    import math
    from types import SimpleNamespace

    from isettorch.isp.chart import patch_means, scene_window

    res = SimpleNamespace(raw=SimpleNamespace(data=torch.zeros(1, 1, 400, 600)),
                          optical_image=SimpleNamespace(image_distance_m=torch.tensor([4e-3]), focal_length_m=None),
                          scene=SimpleNamespace(hfov_deg=torch.tensor([10.0]), vfov_deg=torch.tensor([6.0])))
    half_w = 4e-3 * math.tan(math.radians(5.0)) / 2e-6  # 174.98 pixels
    half_h = 4e-3 * math.tan(math.radians(3.0)) / 2e-6  # 104.82 pixels
    assert scene_window(res, 2e-6) == (round(200 - half_h), round(200 + half_h), round(300 - half_w),
                                       round(300 + half_w)) == (95, 305, 125, 475)
    for bad in (-2e-6, 0.0, float("nan"), "2e-6", True):
        with pytest.raises(ValueError, match="^pixel_size_m: expected a positive, finite pixel pitch"):
            scene_window(res, bad)
    with pytest.raises(ValueError, match=r"^fraction: expected a number in \(0, 1\]"):
        patch_means(torch.zeros(1, 3, 8, 12), fraction=torch.tensor(0.5))


def test_white_balance_checks_its_white_and_flags():
    """A (2, 1, 3) white gave (2, 2, 3) gains for a batch of 2 (documented (B, C)); a (3, 3) one a bare broadcasting
    error. SensorToXYZ(white_preserving='False') was True (bool()), and ImageProcessor(adapt_to_display_white='no')
    turned the Bradford adaptation on. A (B, C) white gives each item its own target."""
    from isettorch.isp.colour import SensorToXYZ
    from isettorch.isp.pipeline import ImageProcessor

    img = torch.rand(2, 3, 4, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64) + 0.1
    per_item = torch.tensor([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]], dtype=torch.float64)
    gains = gray_world_gains(img, per_item)
    means = img.mean(dim=(-2, -1)) * gains
    torch.testing.assert_close(means / means[:, :1], per_item / per_item[:, :1])
    for fn in (gray_world_gains, white_world_gains):
        for bad in (torch.ones(2, 1, 3), torch.ones(3, 3), torch.ones(4)):
            with pytest.raises(ValueError, match=r"^white: expected shape \(3,\) or \(2, 3\)"):
                fn(img, bad)
    with pytest.raises(TypeError, match=r"^white_preserving: expected True or False"):
        SensorToXYZ(white_preserving="False")
    with pytest.raises(TypeError, match=r"^adapt_to_display_white: expected True or False"):
        ImageProcessor(adapt_to_display_white="no", display="crt")


def test_correction_white_and_surfaces_are_named_and_an_spd_white_adapts():
    """correction_white=5 was reported as 'illuminant: ...'; an SPD correction_white with adapt_to_display_white
    failed as 'adapt_from: expected ... a white's XYZ' (the SPD was passed on as an XYZ); SensorToXYZ(surfaces='foo')
    was accepted and failed at the fit as 'name: ...'. An SPD white now adapts as its name does."""
    from isettorch import spectral
    from isettorch.isp.colour import SensorToXYZ
    from isettorch.isp.pipeline import ImageProcessor

    with pytest.raises(ValueError, match=r"^correction_white: expected an energy SPD with 81 samples"):
        ImageProcessor(correction_white=5)
    with pytest.raises(ValueError, match=r"^surfaces: unknown reflectance set 'foo'"):
        SensorToXYZ(surfaces="foo")
    w = spectral.default_wavelengths(380.0, 780.0, 5.0, dtype=torch.float64)
    spd = spectral.illuminant("D65", w, dtype=torch.float64)
    by_spd = ImageProcessor(correction_white=spd, adapt_to_display_white=True, display="crt")
    by_name = ImageProcessor(correction_white="D65", adapt_to_display_white=True, display="crt")
    torch.testing.assert_close(by_spd.xyz_to_display.adaptation, by_name.xyz_to_display.adaptation)
    a = by_name.xyz_to_display.adaptation
    assert not torch.allclose(a, torch.eye(3, dtype=a.dtype))


def test_a_display_matrix_may_be_a_numpy_array_or_a_list():
    """XYZToDisplay's error lists a (3, 3) RGB->XYZ matrix as accepted, but only a torch tensor was: a NumPy array
    or a list failed as a display without primaries."""
    from isettorch.isp.colour import XYZToDisplay

    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    ref = XYZToDisplay(torch.tensor(m)).matrix
    torch.testing.assert_close(XYZToDisplay(m).matrix, ref, rtol=0, atol=0)
    torch.testing.assert_close(XYZToDisplay(m.tolist()).matrix, ref, rtol=0, atol=0)
    torch.testing.assert_close(ref.double() @ torch.tensor(m), torch.eye(3, dtype=torch.float64), atol=1e-6, rtol=0)
