import colour
import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator
from scipy.signal import convolve2d
from skimage.measure import block_reduce

from isettorch.sensor import CFA, SpectralQE, filter_set, ir_cut_filter, isetcam_preblur, isetcam_preblur_kernel
from isettorch.sensor.sampling import isetcam_preblur_size, sample_area, sample_point


def assert_close(actual, expected, rtol=1.3e-6, atol=1e-5):
    """torch.allclose with the error in the message (torch.testing's first call costs seconds of imports)."""
    assert actual.shape == expected.shape, (actual.shape, expected.shape)
    assert torch.allclose(actual, expected, rtol=rtol, atol=atol), (actual - expected).abs().max().item()



def test_colour_camera_sensitivities_match_colour_science():
    w, v, letters = filter_set("nikon_5100", dtype=torch.float64)
    m = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    ref = np.asarray(m.values).T
    # one normalisation: the most sensitive channel peaks at 1, the others keep the measured ratios
    np.testing.assert_allclose(v.numpy(), ref / ref.max(), rtol=1e-12)
    np.testing.assert_allclose(v.numpy().max(axis=1), ref.max(axis=1) / ref.max(), rtol=1e-12)  # NPL: 1, 1, 1
    assert float(v.max()) == 1.0 and letters == ("R", "G", "B")
    # resampled onto a coarse grid: linear interpolation, 0 outside the measured 400-680 nm of the Sigma data
    grid = np.array([390.0, 405.0, 500.0, 690.0])
    _, vs, _ = filter_set("sigma_sdmerill", grid, dtype=torch.float64)
    ms = colour.MSDS_CAMERA_SENSITIVITIES["Sigma SDMerill (NPL)"]
    raw = np.asarray(ms.values).T
    raw = raw / raw.max()
    for c in range(3):
        expected = np.interp(grid, ms.wavelengths, raw[c], left=0.0, right=0.0)
        np.testing.assert_allclose(vs[c].numpy(), expected, rtol=1e-12, atol=1e-15)


def test_pair_generator_qe_is_the_filter_set():
    """data.camera_pairs.nikon_d5100_qe is filter_set('nikon_5100') x peak, each channel shifted by s nm
    (its QE at l is the measured one at l - s; linear interpolation, 0 outside the data)."""
    from isettorch.data.camera_pairs import nikon_d5100_qe

    m = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    ref = np.asarray(m.values).T / np.asarray(m.values).max()
    w = np.arange(380.0, 731.0, 7.3)
    got = nikon_d5100_qe(torch.from_numpy(w), 0.4, (0.0, 10.0, -10.0)).numpy()
    for c, s in enumerate((0.0, 10.0, -10.0)):
        np.testing.assert_allclose(got[c], 0.4 * np.interp(w - s, m.wavelengths, ref[c], left=0, right=0),
                                   rtol=1e-12, atol=1e-15)


def test_spectral_qe_resample_and_cache():
    qe = SpectralQE.from_cfa(CFA("GBRG"), ir_filter=ir_cut_filter(torch.arange(400.0, 701.0, 10.0), 650, 10))
    w = torch.tensor([395.0, 455.0, 700.0, 720.0], dtype=torch.float64)
    out = qe(w)
    assert out.shape == (3, 4)
    native = qe.native().numpy()
    for c in range(3):
        np.testing.assert_allclose(out[c].numpy(), np.interp(w.numpy(), np.arange(400, 701, 10), native[c],
                                                             left=0, right=0), rtol=1e-12)
    assert out[:, 0].abs().sum() == 0 and out[:, 3].abs().sum() == 0
    assert qe(w) is qe(w)  # resampled once per grid
    # IR cut: 0.5 at the cutoff, logistic edge
    ir = ir_cut_filter(torch.tensor([650.0, 700.0]), 650, 10)
    np.testing.assert_allclose(ir.numpy(), [0.5, 1 / (1 + np.exp(5))], rtol=1e-6)


def test_cmy_and_errors():
    qe = SpectralQE.from_cfa(CFA("YCMY"))
    w, rgb, _ = filter_set("isetcam_rgb", dtype=torch.float64)
    c, y, m = qe.native()
    assert_close(c, rgb[1] + rgb[2])
    assert_close(y, rgb[0] + rgb[1])
    with pytest.raises(ValueError, match="no filter for CFA channel 'E'"):
        SpectralQE.from_cfa(CFA("RG/EB"))
    with pytest.raises(ValueError, match="filters: expected non-negative"):
        SpectralQE(torch.tensor([[0.5, -0.1]]), torch.tensor([400.0, 500.0]), ["R"])


def test_learnable_filters_nonnegative_and_trainable():
    qe = SpectralQE.from_cfa(CFA("RGGB"), learnable=True)
    assert any(p.requires_grad for p in qe.parameters())
    native0 = qe.native().detach().clone()
    w = torch.arange(400.0, 701.0, 10.0)
    np.testing.assert_allclose(native0.numpy(), filter_set("isetcam_rgb")[1].numpy(), atol=1e-6)
    for _ in range(20):  # plain gradient descent pushing the filters towards zero
        qe.raw_filters.grad = None
        (qe(w) ** 2).sum().backward()
        with torch.no_grad():
            qe.raw_filters -= 10.0 * qe.raw_filters.grad
    assert (qe.native() >= 0).all()
    assert qe.native().sum() < native0.sum()


def test_learnable_filters_stay_transmittances_and_fixed_ones_above_1_are_refused():
    """A softplus kept learnable filters non-negative only: 50 Adam steps (lr 0.1) that maximise the signal took a
    flat 0.9 filter to 5.68 (DESIGN.md: learnable physics is manufacturable at every step; design files refuse
    filters above 1). Now a sigmoid holds them in [0, 1]; fixed filters above 1 are refused like ir_filter's."""
    w = torch.arange(400.0, 701.0, 10.0)
    qe = SpectralQE(torch.full((1, 31), 0.9, dtype=torch.float64), w, ["W"], learnable=True)
    torch.testing.assert_close(qe.native(), torch.full((1, 31), 0.9, dtype=torch.float64), rtol=0, atol=1e-12)
    opt = torch.optim.Adam(qe.parameters(), lr=0.1)
    for _ in range(50):
        opt.zero_grad()
        (-qe(w).sum()).backward()
        opt.step()
    top = float(qe.native().max())
    assert 0.99 < top <= 1.0
    with pytest.raises(ValueError, match=r"^filters: expected transmittances in \[0, 1\] .* maximum of 3"):
        SpectralQE(torch.full((1, 31), 3.0), w, ["W"])


def test_preblur_kernel_is_fspecial():
    k = 5
    g = isetcam_preblur_kernel(k).numpy()
    o = np.arange(k) - (k - 1) / 2
    ref = np.exp(-(o[:, None] ** 2 + o[None] ** 2) / (2 * (k / 4) ** 2))
    np.testing.assert_allclose(g, ref / ref.sum(), rtol=1e-14)
    np.testing.assert_allclose(isetcam_preblur_kernel(2).numpy(), np.full((2, 2), 0.25))
    assert isetcam_preblur_size(2.8e-6, 7.06e-6) == 1
    assert isetcam_preblur_size(3.5e-6, 1e-6) == 4


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_preblur_matches_matlab_conv2_same(k):
    rng = np.random.default_rng(k)
    a = rng.random((2, 9, 11))
    g = isetcam_preblur_kernel(k).numpy()
    out = isetcam_preblur(torch.from_numpy(a)[None], k)[0].numpy()
    for c in range(2):
        full = convolve2d(a[c], g, mode="full")  # MATLAB conv2 'same' keeps full[k//2 : k//2 + n]
        np.testing.assert_allclose(out[c], full[k // 2:k // 2 + 9, k // 2:k // 2 + 11], rtol=1e-12, atol=1e-15)
    if k == 2:  # the half-sample shift of FORMAT.md 4.6 step 2
        np.testing.assert_allclose(out[0, 3, 4], a[0, 3:5, 4:6].mean())
        np.testing.assert_allclose(out[0, 8, 10], a[0, 8, 10] / 4)


def test_point_sampling_matches_scipy_bilinear():
    rng = np.random.default_rng(0)
    img = rng.random((1, 2, 13, 17))
    dx = 1.3e-6
    pitch = 1.7e-6
    rows, cols = 12, 15  # reaches slightly outside the OI on purpose
    out = sample_point(torch.from_numpy(img), torch.tensor([dx], dtype=torch.float64), pitch, rows, cols)[0]
    ys = (np.arange(13) - 6) * dx
    xs = (np.arange(17) - 8) * dx
    py = (np.arange(rows) - (rows - 1) / 2) * pitch
    px = (np.arange(cols) - (cols - 1) / 2) * pitch
    pts = np.stack(np.meshgrid(py, px, indexing="ij"), -1)
    for c in range(2):
        ref = RegularGridInterpolator((ys, xs), img[0, c], bounds_error=False, fill_value=0.0)(pts)
        np.testing.assert_allclose(out[c].numpy(), ref, rtol=1e-10, atol=1e-12)
    assert (out[:, 0, :] == 0).all()  # first row lies outside the OI: ISETCam NaN -> 0


def _aperture_matrix(n, centres, half):
    """Numerical reference: mean over [c - half, c + half] of each sample's basis function (linear between
    samples, constant on the outer half samples, zero beyond), by dense trapezoid integration."""
    m = np.zeros((len(centres), n))
    knots = np.concatenate([[-0.5], np.arange(n), [n - 0.5]])
    for j in range(n):
        vals = np.zeros(n)
        vals[j] = 1.0
        vals = np.concatenate([[vals[0]], vals, [vals[-1]]])
        for i, c in enumerate(centres):
            xs = np.linspace(c - half, c + half, 20001)
            m[i, j] = np.trapezoid(np.interp(xs, knots, vals, left=0, right=0), xs) / (2 * half)
    return m


def test_area_sampling_against_numerical_integration():
    rng = np.random.default_rng(1)
    img = rng.random((1, 1, 12, 18))
    dx, pitch, rows, cols, ff = 1e-6, 2.3e-6, 5, 8, 0.6
    out = sample_area(torch.from_numpy(img), torch.tensor([dx], dtype=torch.float64), pitch, rows, cols, ff,
                      reconstruction="linear")
    half = pitch * np.sqrt(ff) / 2 / dx
    cy = (12 - 1) / 2 + (np.arange(rows) - (rows - 1) / 2) * pitch / dx
    cx = (18 - 1) / 2 + (np.arange(cols) - (cols - 1) / 2) * pitch / dx
    ref = _aperture_matrix(12, cy, half) @ img[0, 0] @ _aperture_matrix(18, cx, half).T
    np.testing.assert_allclose(out[0, 0].numpy(), ref, rtol=1e-7, atol=1e-9)


def test_area_sampling_constant_block_means():
    rng = np.random.default_rng(1)
    img = rng.random((1, 1, 12, 18))
    dx = torch.tensor([1e-6], dtype=torch.float64)
    # pixels of exactly 3 x 3 OI samples, aligned with the OI grid: block means (skimage)
    out = sample_area(torch.from_numpy(img), dx, 3e-6, 4, 6)
    np.testing.assert_allclose(out[0, 0].numpy(), block_reduce(img[0, 0], (3, 3), np.mean), rtol=1e-12)
    # pixels smaller than OI samples: each pixel takes its sample's value
    small = sample_area(torch.from_numpy(img), torch.tensor([2e-6], dtype=torch.float64), 1e-6, 24, 36)
    np.testing.assert_allclose(small[0, 0].numpy(), np.kron(img[0, 0], np.ones((2, 2))), rtol=1e-12)
    # fill factor 1/4: a 1 um photodiode centred between two OI samples on each axis covers half of each
    ff = sample_area(torch.from_numpy(img), dx, 2e-6, 6, 9, fill_factor=0.25)
    np.testing.assert_allclose(ff[0, 0].numpy(), block_reduce(img[0, 0], (2, 2), np.mean), rtol=1e-12)
    with pytest.raises(ValueError, match="reconstruction"):
        sample_area(torch.from_numpy(img), dx, 2e-6, 6, 9, reconstruction="cubic")


@pytest.mark.parametrize("recon", ["constant", "linear"])
def test_area_sampling_conservation(recon):
    img = torch.from_numpy(np.random.default_rng(2).random((1, 2, 12, 12)))
    dx = torch.tensor([1e-6], dtype=torch.float64)
    # 5 x 5 pixels of 2.4 um tiling the 12 x 12 um OI keep the total signal
    tot = sample_area(img, dx, 2.4e-6, 5, 5, reconstruction=recon)
    np.testing.assert_allclose(tot.sum((-1, -2)).numpy() * 2.4**2, img.sum((-1, -2)).numpy(), rtol=1e-12)


def test_area_sampling_linear_limits():
    img = torch.from_numpy(np.random.default_rng(3).random((1, 2, 12, 12)))
    dx = torch.tensor([1e-6], dtype=torch.float64)
    # tiny photodiodes tend to ISETCam's bilinear point sampling
    small = sample_area(img, dx, 0.7e-6, 15, 15, fill_factor=1e-10, reconstruction="linear")
    np.testing.assert_allclose(small.numpy(), sample_point(img, dx, 0.7e-6, 15, 15).numpy(), rtol=0, atol=1e-5)
    # a linear ramp is reproduced exactly inside the image (the mean of a linear function is its centre value)
    ramp = torch.arange(12, dtype=torch.float64).expand(1, 1, 12, 12).clone()
    r = sample_area(ramp, dx, 2e-6, 4, 4, reconstruction="linear")
    np.testing.assert_allclose(r[0, 0, 0].numpy(), 5.5 + (np.arange(4) - 1.5) * 2, rtol=1e-12)


@pytest.mark.parametrize("k", [3, 4])
def test_preblur_gradient_and_float32(k):
    """The separable pre-blur (two 1-D passes; out of place under autograd) is differentiable (gradcheck) and a
    float32 input gives the float64 result to float32 rounding."""
    rng = np.random.default_rng(k)
    a = torch.from_numpy(rng.random((1, 2, 7, 8))).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: isetcam_preblur(x, k), (a,))
    ref = isetcam_preblur(a.detach(), k)
    out = isetcam_preblur(a.detach().float(), k)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out.double(), ref, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("sampler", ["sample_area", "sample_point"])
def test_the_public_samplers_check_their_arguments(sampler):
    """A spacing tensor of another batch gave a (2, 3, 12, 12) result for 8 x 8 pixels, rows=2.7 gave 3 rows, a
    negative pitch zeros (area) or a mirrored image (point), an integer image zeros: each a ValueError naming it."""
    import isettorch.sensor as sensor_pkg

    f = getattr(sensor_pkg, sampler)
    x = torch.rand(1, 3, 12, 12, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    dx = torch.tensor([1e-6])
    assert f(x, dx, 2e-6, 4, 4).shape == (1, 3, 4, 4)
    for args, name in (((x.expand(2, -1, -1, -1), torch.tensor([1e-6] * 3), 2e-6, 4, 4), "oi_sample_spacing_m"),
                       ((x, dx, 2e-6, 2.7, 4), "rows"), ((x, dx, 2e-6, 4, True), "cols"),
                       ((x, dx, -2e-6, 4, 4), "pixel_size_m"), (((x * 10).long(), dx, 2e-6, 4, 4), "x"),
                       # (a negative spacing gave zeros or a mirror, 0 or inf NaN)
                       ((x, torch.tensor([-1e-6]), 2e-6, 4, 4), "oi_sample_spacing_m"),
                       ((x, torch.tensor([0.0]), 2e-6, 4, 4), "oi_sample_spacing_m"),
                       ((x, torch.tensor([float("inf")]), 2e-6, 4, 4), "oi_sample_spacing_m")):
        with pytest.raises(ValueError, match=f"^{name}: expected"):
            f(*args)
    assert torch.equal(f(x, dx, np.float32(2e-6), 4, 4), f(x, dx, float(np.float32(2e-6)), 4, 4))  # NumPy scalars


@pytest.mark.parametrize("ratio", [2.0, 1.0, 0.5])
def test_the_spacing_gradient_at_aligned_edges_is_the_mean_of_the_one_sided_derivatives(ratio):
    """Pixel edges on OI sample edges (pitch = 2, 1 or 1/2 spacings): the area's derivative in the spacing has two
    one-sided values; autograd gives their mean (it gave -0.106 for +1.29 / +1.13 at pitch = 2 spacings, a wrong
    sign, and none through the Sensor's slice at pitch = spacing)."""
    from isettorch.optics.optical_image import OpticalImage
    from isettorch.sensor import Sensor

    x = torch.rand(1, 1, 16, 16, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 1e15
    pitch = ratio * 1e-6
    rows = 6 if ratio >= 1 else 14
    sensor = Sensor(rows=rows, cols=rows, pixel_size_m=pitch, fill_factor=1.0, cfa="W", read_noise_v=0,
                    dark_current_e_per_s=0, shot_noise="off")
    wl = torch.tensor([550.0], dtype=torch.float64)

    def total(d):
        return sensor.electron_rate(OpticalImage(x, wl.clone(), sample_spacing_m=d)).sum()

    d = torch.tensor([1e-6], dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(total(d), d)
    h = 1e-13
    at = float(total(torch.tensor([1e-6], dtype=torch.float64)))
    up = (float(total(torch.tensor([1e-6 + h], dtype=torch.float64))) - at) / h
    down = (at - float(total(torch.tensor([1e-6 - h], dtype=torch.float64)))) / h
    assert float(grad) == pytest.approx(0.5 * (up + down), rel=2e-3)


def test_the_blocked_overlap_matrix_has_the_single_blocks_values_and_gradients(monkeypatch):
    """The overlap matrix is applied in blocks of pixels, each over the samples it touches: the same values, the same
    derivative in the samples, and at aligned edges (pitch = 2 spacings) the same mean of the one-sided derivatives
    in the spacing (the cumulative-integral path this replaced took one side's: -5.9 for the mean +125.0)."""
    import isettorch.sensor.sampling as sampling

    x = torch.rand(1, 1, 32, 32, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    w = torch.linspace(0.3, 1.7, 256, dtype=torch.float64).reshape(1, 1, 16, 16)

    def run():
        xs = x.clone().requires_grad_(True)
        d = torch.full((1,), 1e-6, dtype=torch.float64, requires_grad=True)
        y = sampling.sample_area(xs, d, 2e-6, 16, 16)
        return (y.detach(), *torch.autograd.grad((y * w).sum(), (xs, d)))

    whole = run()
    monkeypatch.setattr(sampling, "_BOX_CHUNK", 3)  # 6 blocks, the last one short
    blocked = run()
    for a, b in zip(whole, blocked):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    assert float(whole[2]) * 1e-6 == pytest.approx(125.0331, abs=1e-3)  # the one-sided -6.745 / +256.811's mean


def test_area_sampling_of_a_large_image_against_numpy_overlaps():
    """Sensors wider than a block of pixels (here 150 x 260): per-item spacings, a photodiode smaller than the pixel and
    a sensor larger than the optical image (the second item's first block of columns lies outside it), against the
    overlap of each photodiode with each sample computed densely in NumPy; aligned 3 x 3 pixels against
    scikit-image's block means."""
    rng = np.random.default_rng(4)
    img = rng.random((2, 2, 130, 140))
    dx = np.array([1.0e-6, 0.5e-6])
    pitch, rows, cols, ff = 1.1e-6, 150, 260, 0.6
    out = sample_area(torch.from_numpy(img), torch.from_numpy(dx), pitch, rows, cols, ff).numpy()

    def overlaps(n_oi, n_px, spacing):
        centre = (n_oi - 1) / 2 + (np.arange(n_px) - (n_px - 1) / 2) * pitch / spacing
        half = pitch * np.sqrt(ff) / 2 / spacing
        m = np.arange(n_oi)
        lo, hi = centre[:, None] - half, centre[:, None] + half
        return np.clip(np.minimum(hi, m + 0.5) - np.maximum(lo, m - 0.5), 0, None) / (2 * half)

    for i in range(2):
        ref = overlaps(130, rows, dx[i]) @ img[i] @ overlaps(140, cols, dx[i]).T
        np.testing.assert_allclose(out[i], ref, rtol=1e-10, atol=1e-13)
    assert (out[1, ..., :64] == 0).all()  # (the case of a block outside the image is met)
    big = rng.random((1, 1, 300, 330))
    blocks = sample_area(torch.from_numpy(big), torch.tensor([1e-6], dtype=torch.float64), 3e-6, 100, 110)
    np.testing.assert_allclose(blocks[0, 0].numpy(), block_reduce(big[0, 0], (3, 3), np.mean), rtol=1e-12)


@pytest.mark.parametrize("reconstruction", ["constant", "linear"])
def test_one_spacing_for_a_batch_samples_every_item_with_it(reconstruction):
    """One spacing (the checks allow 1 or one per item) is every item's: area sampling of a batch of 2 with one
    spacing failed in a reshape, and before the blocked overlap matrix returned a wrongly shaped result."""
    x = torch.rand(2, 3, 40, 50, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    d = torch.tensor([1e-6], dtype=torch.float64)
    out = sample_area(x, d, 2.3e-6, 10, 12, 0.7, reconstruction)
    for i in range(2):  # (to an ulp: a matrix product of another batch size may take another BLAS kernel)
        torch.testing.assert_close(out[i:i + 1], sample_area(x[i:i + 1], d, 2.3e-6, 10, 12, 0.7, reconstruction),
                                   rtol=1e-14, atol=0)


def test_a_few_pixels_over_a_long_optical_image_against_numpy_overlaps():
    """A sensor of fewer pixels than a block over an optical image of more samples than one block spans densely
    (9 pixels over 6000 samples) reads the samples its pixels touch, with the dense overlaps' values."""
    rng = np.random.default_rng(6)
    img = rng.random((1, 2, 3, 6000))
    pitch, ff = 1.7e-6, 0.8
    out = sample_area(torch.from_numpy(img), torch.tensor([1e-6], dtype=torch.float64), pitch, 3, 9, ff).numpy()
    centre = (6000 - 1) / 2 + (np.arange(9) - 4) * pitch / 1e-6
    half = pitch * np.sqrt(ff) / 2 / 1e-6
    m = np.arange(6000)
    cols = np.clip(np.minimum(centre[:, None] + half, m + 0.5) - np.maximum(centre[:, None] - half, m - 0.5), 0, None)
    centre_r = 1 + (np.arange(3) - 1) * pitch / 1e-6
    m_r = np.arange(3)
    rows = np.clip(np.minimum(centre_r[:, None] + half, m_r + 0.5) - np.maximum(centre_r[:, None] - half, m_r - 0.5),
                   0, None)
    ref = rows / (2 * half) @ img[0] @ (cols / (2 * half)).T
    np.testing.assert_allclose(out[0], ref, rtol=1e-10, atol=1e-13)


def test_a_sensor_sized_by_the_oi_keeps_every_whole_pixel():
    """A float32 OI of 32 samples at the pixel pitch spans 31.9999994 pitches: int() lost a CFA cell (30 x 30)."""
    from isettorch.optics.optical_image import OpticalImage
    from isettorch.sensor import Sensor

    for n, pitch in ((32, 2.8e-6), (16, 1.1e-6), (24, 1.9e-6)):
        for dt in (torch.float32, torch.float64):
            oi = OpticalImage(torch.ones(1, 1, n, n, dtype=dt), torch.tensor([550.0], dtype=dt),
                              sample_spacing_m=torch.tensor([pitch], dtype=dt))
            assert Sensor(pixel_size_m=pitch).size_for(oi) == (n, n)


def test_the_preblur_size_refuses_a_zero_or_negative_length():
    """isetcam_preblur_size with a zero spacing raised ZeroDivisionError, with a negative pitch it gave 1."""
    assert isetcam_preblur_size(2.8e-6, 1e-6) == 3  # ceil(2.8)
    for args, name in (((2e-6, 0.0), "oi_sample_spacing_m"), ((-2e-6, 1e-6), "pixel_size_m"),
                       ((2e-6, float("nan")), "oi_sample_spacing_m")):
        with pytest.raises(ValueError, match=f"^{name}: expected a finite length > 0"):
            isetcam_preblur_size(*args)


def test_the_cfa_tiling_takes_whole_sizes():
    """cfa.tile(map, 2.5, 4) failed in torch's repeat() with a TypeError; 0 and True were taken."""
    from isettorch.sensor.cfa import tile

    m = torch.tensor([[0, 1], [1, 2]])
    assert tile(m, 3, 5).tolist() == [[0, 1, 0, 1, 0], [1, 2, 1, 2, 1], [0, 1, 0, 1, 0]]
    for size in ((2.5, 4), (0, 4), (True, 4)):
        with pytest.raises(ValueError, match="height, width: expected whole numbers of pixels"):
            tile(m, *size)


def test_fixed_filters_that_require_grad_are_not_cached():
    """A SpectralQE made from a tensor that requires grad (learnable=False) is evaluated per call: its cached result
    kept the first call's graph, so a second backward raised. A new tensor assigned to fixed_filters is seen (the
    cache keyed on the version alone returned the old filters: ratio 1.0 for 0.5)."""
    import torch

    from isettorch.optics import OpticalImage
    from isettorch.sensor import Sensor
    from isettorch.sensor.filters import SpectralQE

    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    f = torch.full((3, w.numel()), 0.5, dtype=torch.float64, requires_grad=True)
    qe = SpectralQE(f, w, ["R", "G", "B"])
    grid = torch.arange(405.0, 696.0, 10.0, dtype=torch.float64)  # midpoints: each value the mean of two samples
    for _ in range(2):
        qe(grid).sum().backward()
    # each midpoint's linear interpolation weights 1/2 + 1/2 on its neighbours: the inner samples are used twice
    expected = torch.ones(3, w.numel(), dtype=torch.float64)
    expected[:, [0, -1]] = 0.5
    torch.testing.assert_close(f.grad, 2 * expected)
    # through a sensor's cached QE as well (two optimisation steps' backward passes)
    sensor = Sensor(rows=4, cols=4, spectral_qe=qe)
    oi = OpticalImage(torch.ones(1, w.numel(), 4, 4, dtype=torch.float64), w, sample_spacing_m=sensor.pixel_size_m)
    f.grad = None
    for _ in range(2):
        sensor.qe(oi).sum().backward()
    torch.testing.assert_close(f.grad, torch.full_like(f, 2.0))
    # a fixed QE whose filters are replaced reads the new ones
    fixed = SpectralQE(torch.full((3, w.numel()), 0.5, dtype=torch.float64), w, ["R", "G", "B"])
    before = fixed(grid).clone()
    fixed.fixed_filters = fixed.fixed_filters * 0.5
    torch.testing.assert_close(fixed(grid), before * 0.5)
    # and an IR filter edited in place (the key held the filters alone), through the sensor's cache too
    sensor = Sensor(rows=4, cols=4, spectral_qe=fixed)
    first = sensor.qe(oi).clone()
    with torch.no_grad():
        fixed.extra.mul_(0.5)
    torch.testing.assert_close(fixed(grid), before * 0.25)
    torch.testing.assert_close(sensor.qe(oi), first * 0.5)


def test_a_frozen_banks_new_rows_reach_the_sensor():
    """A frozen FilterBank writes its learned rows into its fixed filters when it runs; the sensor's QE cache, keyed
    before that, kept the old rows after the parameters changed (three calls, then an edit: stale)."""
    import torch

    from isettorch.optics import OpticalImage
    from isettorch.sensor import Sensor
    from isettorch.sensor.filter_bank import FilterBank

    bank = FilterBank(["learned", "learned", "learned"], names=["R", "G", "B"]).freeze()
    sensor = Sensor(rows=4, cols=4, spectral_qe=bank)
    w = bank.wavelengths_nm
    oi = OpticalImage(torch.ones(1, w.numel(), 4, 4, dtype=torch.float64), w, sample_spacing_m=sensor.pixel_size_m)
    for _ in range(3):
        sensor.qe(oi)
    with torch.no_grad():
        bank.raw_amplitudes.mul_(0.5)
    torch.testing.assert_close(sensor.qe(oi), bank(w).to(torch.float64))
    fresh = FilterBank(["learned"] * 3, names=["R", "G", "B"])
    assert not torch.equal(sensor.qe(oi), Sensor(rows=4, cols=4, spectral_qe=fresh).qe(oi))


def test_user_filter_spectra_and_tables_in_other_units_are_refused():
    """A dict of user spectra on 0.40-0.70 (micrometres) or 4e-7-7e-7 (metres) resampled onto the nm grid as zeros:
    every channel black, with no word. A design's filter table in micrometres was refused only at first use, as
    'the image's 400-700 nm miss the sensor's spectral QE'. A spectrum wholly off the grid is refused too."""
    from isettorch.sensor.filter_bank import FilterBank
    from isettorch.sensor.filters import SpectralQE

    w_nm = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    flat = torch.full((31,), 0.5, dtype=torch.float64)
    qe = SpectralQE.from_cfa(CFA("RGGB"), {k: (w_nm, flat) for k in "RGB"})
    assert torch.allclose(qe.filters, torch.full_like(qe.filters, 0.5))
    for scale in (1e-3, 1e-9):
        with pytest.raises(ValueError, match=r"^filters\['R'\] wavelengths: expected wavelengths in nm"):
            SpectralQE.from_cfa(CFA("RGGB"), {k: (w_nm * scale, flat) for k in "RGB"})
    with pytest.raises(ValueError, match=r"^filters\['R'\]: its 800-1100 nm miss the sensor's grid \(400-700 nm\)"):
        SpectralQE.from_cfa(CFA("RGGB"), {k: (w_nm + 400 if k == "R" else w_nm, flat) for k in "RGB"})
    with pytest.raises(ValueError, match=r"^wavelengths_nm: expected wavelengths in nm"):
        FilterBank.from_table(flat[None].repeat(3, 1), w_nm * 1e-3, ["a", "b", "c"])


def test_an_oi_spacing_changed_in_place_is_resampled():
    """The sensor memoises whether an OI's spacing equals its pitch (the one-sample-per-pixel shortcut); a spacing
    changed in place kept the stale answer: raw samples for a grid twice the pitch (up to 92 % off)."""
    from isettorch.optics.optical_image import OpticalImage
    from isettorch.sensor import Sensor

    wl = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)
    qe = SpectralQE(torch.tensor([0.5, 0.6, 0.7], dtype=torch.float64)[:, None].expand(3, 3).clone(), wl,
                    ["R", "G", "B"])

    def sensor():
        return Sensor(rows=8, cols=8, pixel_size_m=1e-6, fill_factor=1.0, cfa="RGGB", spectral_qe=qe)

    photons = torch.rand(1, 3, 16, 16, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 1e15
    oi = OpticalImage(photons, wl, sample_spacing_m=torch.tensor([1e-6], dtype=torch.float64))
    s = sensor()
    s.electron_rate(oi)
    oi.sample_spacing_m.mul_(2)
    torch.testing.assert_close(s.electron_rate(oi), sensor().electron_rate(oi), rtol=1e-12, atol=0)
    # a positive pitch given as a tensor is refused for being a tensor, not told it is not positive
    with pytest.raises(ValueError, match=r"pixel_size_m: expected a positive number, got tensor.*not a tensor"):
        Sensor(rows=8, cols=8, pixel_size_m=torch.tensor(2e-6), spectral_qe=qe)
    with pytest.raises(ValueError, match=r"pixel_size_m: expected a finite pitch > 0 .*not a tensor"):
        sample_area(photons[:, :1], torch.tensor([1e-6], dtype=torch.float64), torch.tensor(2e-6), 4, 4)
