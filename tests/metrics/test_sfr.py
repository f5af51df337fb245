"""ISO 12233 e-SFR on slanted edges built independently from an analytic MTF (diffraction x pixel aperture)."""

import math

import numpy as np
import pytest
import torch
from scipy.optimize import brentq

from isettorch.metrics import esfr

WAVELENGTH_M = 550e-9
PITCH_M = 4e-6
ANGLE_DEG = 5.0


def analytic_otf(f_cy_px, f_number, theta_rad):
    """Diffraction OTF of a circular pupil (Goodman, Introduction to Fourier Optics, eq. 6-32) times the
    100%-fill square pixel aperture, along the normal of an edge at theta from the vertical."""
    fc = PITCH_M / (WAVELENGTH_M * f_number)  # incoherent cutoff 1/(lambda N), in cycles/pixel
    s = np.clip(f_cy_px / fc, 0, 1)
    diffraction = 2 / np.pi * (np.arccos(s) - s * np.sqrt(1 - s * s))
    return diffraction * np.sinc(f_cy_px * np.cos(theta_rad)) * np.sinc(f_cy_px * np.sin(theta_rad))


def slanted_edge(f_number, height=96, width=64, angle_deg=ANGLE_DEG, centre=None, low=0.1, high=0.9):
    """Point-sampled edge image. ESF(d) = 1/2 + (1/pi) int_0^fc OTF(f) sin(2 pi f d) / f df (the integral of the
    LSF, itself the inverse transform of the real, even, band-limited OTF), by Gauss-Legendre quadrature,
    at each pixel centre's signed distance d from the edge."""
    th = math.radians(angle_deg)
    fc = PITCH_M / (WAVELENGTH_M * f_number)
    x, w = np.polynomial.legendre.leggauss(600)
    f, w = fc * (x + 1) / 2, w * fc / 2
    cy, cx = centre if centre is not None else ((height - 1) / 2, (width - 1) / 2)
    yy, xx = np.mgrid[0:height, 0:width].astype(float)
    # signed distance, bright side positive; a positive angle tilts the top of the edge to the right (y down),
    # the convention of isettorch.scene.slanted_edge and of esfr's angle_deg
    d = ((xx - cx) * np.cos(th) + (yy - cy) * np.sin(th)).ravel()
    esf = 0.5 + 2 * d * (np.sinc(2 * np.outer(d, f)) @ (analytic_otf(f, f_number, th) * w))
    return torch.tensor(low + (high - low) * esf.reshape(height, width))


def analytic_mtf50(f_number, theta_rad=0.0):
    return brentq(lambda f: analytic_otf(f, f_number, theta_rad) - 0.5, 0.01, 1.0)


@pytest.fixture(scope="module")
def edges():
    return {n: slanted_edge(n) for n in (4, 8)}


@pytest.mark.parametrize("f_number,expected", [(4, 0.4353), (8, 0.3026)])
def test_mtf50_matches_analytic(edges, f_number, expected):
    # the test's own model reproduces the stated analytic values
    assert analytic_mtf50(f_number) == pytest.approx(expected, abs=1e-4)
    res = esfr(edges[f_number], auto_roi=False)
    assert float(res.mtf50) == pytest.approx(expected, rel=0.02)
    assert float(res.angle_deg) == pytest.approx(ANGLE_DEG, abs=0.05)
    # the whole curve up to Nyquist and the value at Nyquist
    f = res.frequencies.numpy()
    keep = f <= 0.5
    ref = analytic_otf(f[keep], f_number, math.radians(ANGLE_DEG))
    assert np.abs(res.sfr.numpy()[keep] - ref).max() < 0.02
    assert float(res.mtf_nyquist) == pytest.approx(analytic_otf(0.5, f_number, math.radians(ANGLE_DEG)), abs=0.01)


def test_orientation_and_polarity_invariance(edges):
    img = edges[8]
    base = esfr(img, auto_roi=False)
    # transposing an edge tilted by a from the vertical gives one tilted by 90 - a; mirroring gives -a
    a = float(base.angle_deg)
    for variant, angle in ((img.T, 90 - a), (img.flip(-1), -a), (img.flip(-2).T, -90 + a)):
        r = esfr(variant, auto_roi=False)
        assert float(r.mtf50) == pytest.approx(float(base.mtf50), rel=1e-6)
        assert float(r.angle_deg) == pytest.approx(angle, abs=1e-6)
    assert bool(esfr(img.T, auto_roi=False).horizontal)


def test_auto_roi_in_larger_image():
    img = slanted_edge(4, height=120, width=110, centre=(60.0, 70.0))
    res = esfr(img)
    r0, r1, c0, c1 = res.roi[0]
    assert c0 < 70 - 120 * math.tan(math.radians(ANGLE_DEG)) / 2 and c1 > 70 + 5
    assert r1 - r0 >= 80
    assert float(res.mtf50) == pytest.approx(0.4353, rel=0.02)


def test_batched_channels_and_gradient(edges):
    img = torch.stack([edges[4], edges[8]]).unsqueeze(1).repeat(1, 3, 1, 1).float().requires_grad_()
    res = esfr(img, auto_roi=False)
    assert res.sfr.shape[:2] == (2, 3) and res.mtf50.shape == (2, 3)
    assert res.sfr.dtype == torch.float32
    np.testing.assert_allclose(res.mtf50[:, 0].detach().numpy(), [0.4353, 0.3026], rtol=0.02)
    (g,) = torch.autograd.grad(res.mtf50.sum(), img)
    assert torch.isfinite(g).all() and g.abs().sum() > 0


def test_bad_input():
    flat = torch.full((40, 40), 0.5)
    with pytest.raises(ValueError, match="edge"):
        esfr(flat)
    straight = torch.zeros(40, 40)
    straight[:, 20:] = 1.0
    with pytest.raises(ValueError, match="slant"):
        esfr(straight, auto_roi=False)
    with pytest.raises(ValueError, match="roi"):
        esfr(straight, roi=(0, 50, 0, 10))


def test_noisy_edge_and_plot(edges):
    g = torch.Generator().manual_seed(0)
    noisy = edges[4] + 0.005 * torch.randn(edges[4].shape, generator=g, dtype=torch.float64)
    res = esfr(noisy, auto_roi=False)
    assert float(res.mtf50) == pytest.approx(0.4353, rel=0.03)
    fig = res.plot(pixel_pitch_m=PITCH_M)
    assert len(fig.axes[0].lines) == 3  # the SFR and the two guide lines


def test_too_few_rows_for_oversampling():
    # 1 degree over 12 rows: the edge moves 0.2 px, so most 4x bins stay empty
    img = slanted_edge(8, height=12, width=32, angle_deg=1.0)
    with pytest.raises(ValueError, match="empty"):
        esfr(img, auto_roi=False)


@pytest.mark.parametrize("offset_px", [-24.0, -12.0, 12.0, 24.0])
def test_off_centre_edge_matches_analytic(offset_px):
    """An edge 12-24 px off the centre of a 64 px wide ROI: the ESF grid (centred on the edge) reaches past the
    data on the short side, which is not a lack of rows; the MTF50 is the analytic one as for a centred edge."""
    img = slanted_edge(8, centre=(47.5, 31.5 + offset_px))
    res = esfr(img, auto_roi=False)
    assert float(res.mtf50) == pytest.approx(analytic_mtf50(8), rel=0.02)


def test_low_contrast_edge_on_a_high_pedestal():
    """A noise-free edge of 1 DN on a 1000 DN black level is an edge (not 'flat'): the same MTF50 as at full
    contrast (the e-SFR normalises the contrast away)."""
    img = slanted_edge(8, low=1000.0, high=1001.0)
    assert float(esfr(img, auto_roi=False).mtf50) == pytest.approx(analytic_mtf50(8), rel=0.02)
    # the automatic ROI too: zero padding made the frame's border a 1000 DN step that beat the 1 DN edge ('flat')
    auto = esfr(img)
    assert auto.roi[0] == esfr(slanted_edge(8)).roi[0]
    assert float(auto.mtf50) == pytest.approx(analytic_mtf50(8), rel=0.02)


@pytest.mark.parametrize("angle", [-80.0, -60.0, -30.0, -5.0, 5.0, 30.0, 60.0, 80.0])
def test_angle_sign_matches_slanted_edge(angle):
    # Friction 9 of issue 18: esfr reported the opposite sign of the scene generator's angle.
    from isettorch.scene import slanted_edge as scene_edge

    img = scene_edge(96, angle).reflectance()[0, 15]  # exact area coverage: the edge is where the scene puts it
    assert float(esfr(img, auto_roi=False).angle_deg) == pytest.approx(angle, abs=0.1)


def test_flat_and_noisy_input_raise_instead_of_nan(edges):
    # Friction 10 of issue 18: flat or noise-dominated ROIs gave nan or noise curves without a word.
    with pytest.raises(ValueError, match="no edge in the ROI"):
        esfr(torch.full((64, 64), 0.5, dtype=torch.float64), auto_roi=False)
    img = edges[8]  # contrast 0.8
    g = torch.Generator().manual_seed(0)
    noisy = img + (0.8 / 3) * torch.randn(img.shape, generator=g, dtype=img.dtype)  # CNR 3
    msg = r"too noisy.*contrast 0\.[78]\d*.*noise sigma 0\.2[4-9]\d* = [23]\.\d+ < min_cnr 10"
    with pytest.raises(ValueError, match=msg):
        esfr(noisy, auto_roi=False)
    # min_cnr 0: the caller takes the noisy answer knowingly
    assert torch.isfinite(esfr(noisy, auto_roi=False, min_cnr=0).sfr).all()
    # a mildly noisy edge (CNR 40) passes, with an MTF50 close to the noise-free one
    mild = img + (0.8 / 40) * torch.randn(img.shape, generator=g, dtype=img.dtype)
    assert float(esfr(mild, auto_roi=False).mtf50) == pytest.approx(float(esfr(img, auto_roi=False).mtf50), rel=0.1)


@pytest.mark.parametrize("roi", [(40, 10, 0, 64), (0, 64, 50, 10), (10, 10, 0, 64), (-1, 64, 0, 64)])
def test_inverted_or_empty_roi_is_rejected(edges, roi):
    with pytest.raises(ValueError, match=r"roi: .*row0 < row1"):
        esfr(edges[8], roi=roi)


@pytest.mark.parametrize("kw", [{"min_cnr": -1.0}, {"max_empty_bins": 1.5}])
def test_bad_thresholds(edges, kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        esfr(edges[8], auto_roi=False, **kw)


def _box_pixel_mtf50():
    return brentq(lambda f: np.sinc(f) - 0.5, 0.1, 0.9)  # 100 % fill square pixel: MTF = sinc(f), 0.6034 cy/px


def test_cfa_aware_sfr_on_a_bayer_mosaic():
    # Friction 2 of issue 18: e-SFR of a raw mosaic. An exact-area edge (box pixels, no optics) seen through a
    # GRBG mosaic whose filters have gains R 1, G 1.5, B 2: the true MTF is the pixel's sinc in every channel.
    from isettorch.metrics import esfr_cfa
    from isettorch.scene import slanted_edge as scene_edge
    from isettorch.sensor import CFA

    edge = scene_edge(128, 5.0).reflectance()[0, 15]
    mosaic = edge * (CFA("GRBG").index_map.repeat(64, 64).double() * 0.5 + 1)
    with pytest.raises(ValueError, match="too noisy"):  # the plain e-SFR sees the CFA pattern as noise
        esfr(mosaic)
    lum = esfr_cfa(mosaic, "GRBG")
    assert float(lum.mtf50) == pytest.approx(float(esfr(edge, auto_roi=False).mtf50), rel=0.01)
    assert float(lum.mtf50) == pytest.approx(_box_pixel_mtf50(), rel=0.04)
    ch = esfr_cfa(mosaic, "GRBG", mode="channels")
    assert ch.channels == ("R", "G", "B") and ch.sfr.shape[0] == 3
    for m in ch.mtf50.tolist():
        assert m == pytest.approx(_box_pixel_mtf50(), rel=0.05)
    assert ch.angle_deg.tolist() == pytest.approx([5.0] * 3, abs=0.05)
    with pytest.raises(ValueError, match="mode"):
        esfr_cfa(mosaic, "GRBG", mode="rgb")


@pytest.mark.filterwarnings("ignore:the scene is coarser")
def test_cfa_aware_sfr_through_the_camera_orders_channels_by_wavelength():
    # Diffraction blur grows with wavelength (cutoff 1 / (lambda N)): R's MTF50 < G's < B's.
    import isettorch
    from isettorch.metrics import esfr_cfa
    from isettorch.scene import slanted_edge as scene_edge

    cam = isettorch.Camera.from_config("default")
    cam.noise = False
    f, p = float(cam.optics.focal_length_m), cam.sensor.pixel_size_m
    hfov = math.degrees(2 * math.atan(128 * p / (2 * f)))
    raw = cam(scene_edge(512, hfov_deg=hfov), return_intermediates=True).raw
    r, g, b = esfr_cfa(raw.noise_free[0, 0], raw.cfa, mode="channels").mtf50.tolist()
    assert r < g < b
    lum = float(esfr_cfa(raw.noise_free[0, 0], raw.cfa).mtf50)
    assert r < lum < b


def test_a_roi_with_two_edges_is_refused():
    """A bar (an edge up and one down) in the ROI passed every check and gave a meaningless curve (MTF50 0.116 for
    a true 0.267); its edge profile starts and ends at one level, which one edge's never does."""
    up = slanted_edge(4, width=64, centre=(47.5, 20.0))
    down = slanted_edge(4, width=64, centre=(47.5, 44.0))
    with pytest.raises(ValueError, match="more than one edge"):
        esfr(up - down + 0.1, auto_roi=False)
    assert math.isfinite(float(esfr(up, auto_roi=False).mtf50))  # either edge alone is measured
    # a bar whose two sides are at one level exactly was called "flat" (the mean levels of its outer quarters
    # agree): it is named as what it is
    from scipy.special import ndtr

    y, x = np.mgrid[0:64, 0:64].astype(float)
    t = math.tan(math.radians(5))

    def soft(xc):
        return ndtr(((x - xc) + t * (y - 31.5)) * math.cos(math.radians(5)))

    bar = torch.from_numpy(0.2 + 0.6 * np.minimum(soft(20), 1 - soft(44)))
    with pytest.raises(ValueError, match=r"no single edge in the ROI: its two sides have the same mean level .* "
                                         r"spans 0\.2\.\.0\.8"):
        esfr(bar, auto_roi=False)
    with pytest.raises(ValueError, match="no edge in the ROI"):  # a truly flat ROI is still "flat"
        esfr(torch.full((40, 40), 0.5), auto_roi=False)
    # a too-small ROI is reported in the shape given, also for a near-horizontal edge (it was shown transposed)
    with pytest.raises(ValueError, match="at least 8x8 pixels, got 64x7"):
        esfr(torch.from_numpy(ndtr((y - 31.5) + t * (x - 31.5)))[:, 10:17], auto_roi=False)
    # one edge with what real ROIs carry is still one edge: a sharpened edge's halos (an unsharp mask of 15 px,
    # amount 3: 56 % overshoot each side) and a 70 % vignetting fall-off across the ROI
    e = slanted_edge(4)
    blur = torch.nn.functional.avg_pool2d(torch.nn.functional.pad(e[None, None], (7, 7, 7, 7), mode="replicate"),
                                          15, 1)[0, 0]
    sharpened = e + 3.0 * (e - blur)
    assert float((sharpened.mean(0).max() - 0.9) / 0.8) > 0.5
    vignetted = e * (1 - 0.7 * torch.linspace(0, 1, e.shape[1], dtype=e.dtype))[None]
    for img in (sharpened, vignetted):
        assert math.isfinite(float(esfr(img, auto_roi=False).mtf50))


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_edges_are_measured_in_float32(edges, dtype):
    """The CPU's FFT takes no half precision: esfr raised torch's unnamed "Unsupported dtype Half"; the other metrics
    compute half precision in float32."""
    res = esfr(edges[4].to(dtype), auto_roi=False)
    assert float(res.mtf50) == pytest.approx(0.4353, rel=0.03)  # the analytic value (rounding of the input: 1e-3)


def test_the_noise_check_holds_on_integer_data():
    # A 2 DN edge on 100 DN (Gaussian blur 1 px, 5 deg), 0.4 DN noise, rounded to integers: most vertical
    # differences are 0, so the MAD noise estimate was 0 and min_cnr's check was skipped (MTF50 up to 16 % low,
    # CNR about 4.3). The same frame in float was refused. A 60 DN edge with the same noise is measured: MTF50 within
    # 3 % of exp(-2 pi^2 s^2 f^2)'s.
    from scipy.special import erf

    h, w, th = 128, 64, math.radians(5)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    d = (xx - (w - 1) / 2) * math.cos(th) + (yy - (h - 1) / 2) * math.sin(th)
    ramp = 0.5 * (1 + erf(d / math.sqrt(2)))
    noise = 0.4 * np.random.default_rng(0).standard_normal((h, w))
    with pytest.raises(ValueError, match="too noisy"):
        esfr(torch.tensor(np.round(100 + 2 * ramp + noise)), auto_roi=False)
    res = esfr(torch.tensor(np.round(100 + 60 * ramp + noise)), auto_roi=False)
    assert float(res.mtf50) == pytest.approx(math.sqrt(math.log(2) / (2 * math.pi ** 2)), rel=0.03)


def test_a_roi_is_whole_pixels_and_the_cfa_roi_reported_is_the_one_measured():
    # esfr truncated roi=(0.5, 100.7, 0, 64) to (0, 100, 0, 64) (snr_uniform refuses it); esfr_cfa widened
    # (3, 128, 33, 97) to whole 2 x 2 cells, (2, 128, 32, 97), and reported the ROI asked for (luminance mode: the
    # crop's own extent, (0, 126, 0, 65)).
    from isettorch.metrics import esfr_cfa
    from isettorch.scene import slanted_edge as scene_edge
    from isettorch.sensor import CFA

    edge = scene_edge(128, 5.0).reflectance()[0, 15]
    with pytest.raises(ValueError, match=r"roi: expected \(row0, row1, col0, col1\) integers"):
        esfr(edge, roi=(0.5, 100.7, 0, 64))
    mosaic = edge * (CFA("GRBG").index_map.repeat(64, 64).double() * 0.5 + 1)
    for mode in ("luminance", "channels"):
        res = esfr_cfa(mosaic, "GRBG", mode=mode, roi=(3, 128, 33, 97))
        assert all(r == (2, 128, 32, 97) for r in res.roi)
    with pytest.raises(ValueError, match="roi"):
        esfr_cfa(mosaic, "GRBG", roi=(3.5, 128, 33, 97))


def test_an_edge_leaving_the_roi_through_a_side_is_refused():
    """An edge at 10 deg through column 3 of a 100 px ROI leaves it through the left side for a third of the rows:
    their centroids were noise, the fitted line biased, and the MTF50 read 0.139 for a true sqrt(ln 2 / (2 pi^2)) /
    sigma = 0.187 cy/px (angle 7.0 deg for 10) without a word. Refused; the same edge through column 10, which
    crosses every row, gives the analytic value."""
    from scipy.special import erf

    y, x = np.mgrid[0:100, 0:100].astype(float)
    t = math.radians(10)

    def edge(cx):  # Gaussian blur sigma 1 px: ESF 0.5 (1 + erf(d / sqrt 2))
        d = (x - cx) * math.cos(t) - (y - 49.5) * math.sin(t)
        return torch.tensor(0.1 + 0.8 * 0.5 * (1 + erf(d / math.sqrt(2))))

    with pytest.raises(ValueError, match=r"image: the edge leaves the ROI through a side \(at columns -1\.9 and"):
        esfr(edge(3.0), auto_roi=False)
    res = esfr(edge(10.0), auto_roi=False)
    assert float(res.mtf50) == pytest.approx(math.sqrt(math.log(2) / (2 * math.pi**2)), rel=0.01)
    assert abs(float(res.angle_deg)) == pytest.approx(10.0, abs=0.1)
