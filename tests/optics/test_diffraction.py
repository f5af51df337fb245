"""Diffraction-limited optics: Airy pattern, MTF, power, linear convolution, batching, pad modes."""

import math

import numpy as np
import pytest
import torch
from scipy import special

from isettorch import Scene
from isettorch.optics import DiffractionLimitedOptics, geometry
from isettorch.optics.diffraction import dl_mtf_1d, dl_otf

F = 4e-3
FAR = 1e4  # scene distance: image distance = f to 1.6e-7


def _point_scene(n=64, lam_n_over_dx=16.0, wave=(550.0,), fnum=4.0, pos=None, dtype=torch.float64):
    """A one-sample point source on an n x n scene whose image-plane spacing is lambda N / lam_n_over_dx."""
    lam = wave[0] * 1e-9
    dx = lam * fnum / lam_n_over_dx
    d_i = 1 / (1 / F - 1 / FAR)
    hfov = 2 * math.degrees(math.atan(n * dx / (2 * d_i)))
    x = torch.zeros(1, len(wave), n, n, dtype=dtype)
    r, c = pos or (n // 2, n // 2)
    x[:, :, r, c] = 1.0
    return Scene(x, torch.tensor(wave, dtype=dtype), hfov_deg=hfov, distance_m=FAR), dx


def _radial_profile(img, r0, c0):
    return img[r0, c0:]


def test_airy_pattern():
    scene, dx = _point_scene()
    optics = DiffractionLimitedOptics(4.0, F, relative_illumination=None)
    oi = optics(scene)
    assert oi.sample_spacing_m.item() == pytest.approx(dx, rel=1e-6)
    img = oi.photons[0, 0].numpy()
    r0, c0 = np.unravel_index(np.argmax(img), img.shape)
    prof = img[r0, c0:] / img[r0, c0]
    lam_n = 550e-9 * 4.0
    # first dark ring: discrete minimum refined by a parabola
    i = int(np.argmax(np.diff(prof) > 0))
    a, b, c = prof[i - 1], prof[i], prof[i + 1]
    ring = (i + 0.5 * (a - c) / (a - 2 * b + c)) * dx / lam_n
    assert ring == pytest.approx(1.2197, rel=1e-2)
    # FWHM: linear interpolation of the half-maximum crossing
    j = int(np.argmax(prof < 0.5))
    half = (j - 1 + (prof[j - 1] - 0.5) / (prof[j - 1] - prof[j])) * dx
    assert 2 * half / lam_n == pytest.approx(1.0290, rel=1e-2)
    # encircled energy inside the first dark ring
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    r = np.hypot(yy - r0, xx - c0) * dx
    ee = img[r <= 1.2197 * lam_n].sum() / img.sum()
    assert ee == pytest.approx(0.8378, rel=5e-3)


def test_applied_mtf_is_analytic():
    wave = (450.0, 550.0, 650.0)
    scene, dx = _point_scene(n=48, lam_n_over_dx=1.5, wave=wave)
    optics = DiffractionLimitedOptics(torch.tensor(4.0), F, relative_illumination=None)
    oi = optics(scene)
    pr, pc = oi.pad_rows, oi.pad_cols
    inp = torch.zeros_like(oi.photons)
    inp[:, :, pr + 24, pc + 24] = oi.photons.sum(dim=(-2, -1))  # the irradiance impulse the lens received
    mtf = (torch.fft.fft2(oi.photons).abs() / torch.fft.fft2(inp).abs())[0].numpy()
    my, mx = oi.photons.shape[-2:]
    fy, fx = np.fft.fftfreq(my, dx), np.fft.fftfreq(mx, dx)
    rho = np.hypot(fy[:, None], fx[None, :])
    for k, lam in enumerate(wave):
        s = np.minimum(rho * lam * 1e-9 * 4.0, 1.0)
        ref = 2 / np.pi * (np.arccos(s) - s * np.sqrt(1 - s * s))
        assert np.abs(mtf[k] - ref).max() < 1e-3


@pytest.mark.parametrize("distance_m", [12e-3, 0.1])
def test_applied_mtf_at_a_finite_distance_has_the_working_f_number(distance_m):
    # A lens focused at d_o images through a converging wave of radius d_i, not f: the incoherent cutoff is
    # D / (lambda d_i) = 1 / (lambda N (1 + |m|)), the working f-number N d_i / f (Goodman, Introduction to
    # Fourier Optics, 3rd ed., 6.3.2). At 12 mm a 4 mm lens works at 1.5 N (before, its MTF stayed N's: 0.25 off
    # the working f-number's at 12 mm, 0.026 at 0.1 m).
    wave, fnum, n = (550.0,), 4.0, 48
    d_i = 1 / (1 / F - 1 / distance_m)
    dx = 550e-9 * fnum * d_i / F / 1.5
    hfov = 2 * math.degrees(math.atan(n * dx / (2 * d_i)))
    x = torch.zeros(1, 1, n, n, dtype=torch.float64)
    x[:, :, n // 2, n // 2] = 1.0
    scene = Scene(x, torch.tensor(wave, dtype=torch.float64), hfov_deg=hfov, distance_m=distance_m)
    oi = DiffractionLimitedOptics(fnum, F, relative_illumination=None)(scene)
    assert oi.sample_spacing_m.item() == pytest.approx(dx, rel=1e-9)
    assert oi.image_distance_m.item() == pytest.approx(d_i, rel=1e-12)
    pr, pc = oi.pad_rows, oi.pad_cols
    inp = torch.zeros_like(oi.photons)
    inp[:, :, pr + n // 2, pc + n // 2] = oi.photons.sum(dim=(-2, -1))
    mtf = (torch.fft.fft2(oi.photons).abs() / torch.fft.fft2(inp).abs())[0, 0].numpy()
    my, mx = oi.photons.shape[-2:]
    rho = np.hypot(np.fft.fftfreq(my, dx)[:, None], np.fft.fftfreq(mx, dx)[None, :])
    s = np.minimum(rho * 550e-9 * fnum * d_i / F, 1.0)
    ref = 2 / np.pi * (np.arccos(s) - s * np.sqrt(1 - s * s))
    assert np.abs(mtf - ref).max() < 1e-3


def test_otf_of_a_large_grid_by_wavelength_chunks_is_the_same(monkeypatch):
    # Without a gradient a large grid's OTF is evaluated a few wavelengths at a time (bounded temporaries): the same
    # values as all at once (the MTF is element-wise; bitwise here, where each chunk of 7,920 values is whole SIMD
    # vectors), Goodman's formula at every wavelength; with a gradient (a learnable f-number) all at once, the
    # gradient unchanged.
    from isettorch.optics import diffraction, dl_otf

    g = torch.Generator().manual_seed(0)
    fy, fx = torch.randn(2, 40, generator=g) * 2e5, torch.randn(2, 33, generator=g) * 2e5
    wave, n = torch.linspace(400.0, 700.0, 31), torch.tensor([2.0, 5.6])
    whole = dl_otf(fy, fx, wave, n)
    monkeypatch.setattr(diffraction, "_OTF_CHUNK_ELEMENTS", 3 * 2 * 40 * 33)  # three wavelengths at a time
    chunked = dl_otf(fy, fx, wave, n)
    assert torch.equal(chunked, whole)
    rho = torch.sqrt(fy[:, :, None] ** 2 + fx[:, None, :] ** 2)
    s = (rho[:, None] * wave[None, :, None, None] * 1e-9 * n[:, None, None, None]).clamp(max=1.0).double()
    ref = 2 / math.pi * (torch.acos(s) - s * torch.sqrt(1 - s * s))
    torch.testing.assert_close(chunked.double(), ref, rtol=0, atol=1e-6)
    n_learn = n.clone().requires_grad_(True)
    dl_otf(fy, fx, wave, n_learn).sum().backward()
    n_ref = n.clone().requires_grad_(True)
    monkeypatch.setattr(diffraction, "_OTF_CHUNK_ELEMENTS", 1 << 30)
    dl_otf(fy, fx, wave, n_ref).sum().backward()
    assert torch.equal(n_learn.grad, n_ref.grad)


def test_power_conserved_and_camera_equation():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 20, 24, generator=g, dtype=torch.float64) * 1e15
    scene = Scene(x, torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64), hfov_deg=[2.0, 1.0], distance_m=1.2)
    for mode in ("isetcam", "paraxial"):
        optics = DiffractionLimitedOptics([2.0, 8.0], F, relative_illumination=None, camera_equation=mode)
        oi = optics(scene)
        d_i = 1 / (1 / F - 1 / 1.2)
        m = d_i / 1.2
        n = torch.tensor([2.0, 8.0], dtype=torch.float64)
        k = math.pi / (4 * n**2 * (1 + m) ** 2 + (1 if mode == "isetcam" else 0))
        expected = x.sum(dim=(-2, -1)) * k[:, None]
        torch.testing.assert_close(oi.photons.sum(dim=(-2, -1)), expected, rtol=1e-5, atol=0)


def test_linear_convolution_no_wraparound():
    # bright point 1 sample from the left edge; lambda N = 4 dx: a wide PSF on a 32-sample scene
    scene, dx = _point_scene(n=32, lam_n_over_dx=4.0, pos=(16, 1))
    lam_n = 550e-9 * 4.0
    optics = DiffractionLimitedOptics(4.0, F, relative_illumination=None)
    oi = optics(scene)
    pr, pc = oi.pad_rows, oi.pad_cols
    img = oi.photons[0, 0].numpy() / oi.photons.sum().item()
    # the independent answer: the Airy pattern (sampled, band-limited since dx < lambda N / 2) at the right edge
    cols = np.arange(32)
    x = np.pi * np.hypot(0, (cols - 1) * dx) / lam_n
    airy = np.where(x > 0, (2 * special.j1(np.maximum(x, 1e-12)) / np.maximum(x, 1e-12)) ** 2, 1.0)
    airy *= (np.pi / 4) * (dx / lam_n) ** 2  # peak of the normalised PSF times the sample area
    got = img[pr + 16, pc + cols]
    assert abs(got[1] - airy[1]) < 1e-3 * airy[1]
    # values ~1e-5 (peak 0.049): what wraps around is below 1e-6 (2e-5 of the peak); measured 4e-7
    assert np.abs(got[-4:] - airy[-4:]).max() < 1e-6
    # the same blur with no padding (circular over the scene) does leak onto the opposite edge
    wrap = DiffractionLimitedOptics(4.0, F, relative_illumination=None, margin=0)(scene).photons[0, 0].numpy()
    wrap = wrap / wrap.sum()
    assert np.abs(wrap[16, -4:] - airy[-4:]).max() > 1e-3


def test_batched_equals_one_at_a_time():
    g = torch.Generator().manual_seed(1)
    x = torch.rand(2, 2, 16, 20, generator=g, dtype=torch.float64) * 1e15
    w = torch.tensor([500.0, 600.0], dtype=torch.float64)
    both = Scene(x, w, hfov_deg=[0.5, 0.3], distance_m=[1.2, 3.0])
    optics = DiffractionLimitedOptics(torch.tensor([2.8, 11.0], dtype=torch.float64), F, margin=6)
    out = optics(both)
    for i, n in enumerate([2.8, 11.0]):
        one = DiffractionLimitedOptics(n, F, margin=6)(both[i])
        torch.testing.assert_close(out.photons[i:i + 1], one.photons, rtol=1e-10, atol=0)
        torch.testing.assert_close(out.sample_spacing_m[i], one.sample_spacing_m[0])


def test_crop_window_matches_full():
    g = torch.Generator().manual_seed(2)
    x = torch.rand(1, 2, 24, 30, generator=g, dtype=torch.float64) * 1e15
    scene = Scene(x, torch.tensor([450.0, 650.0], dtype=torch.float64), hfov_deg=0.4, distance_m=1.2)
    optics = DiffractionLimitedOptics(4.0, F, psf_tolerance=1e-3)
    full = optics(scene)
    pr, pc = full.pad_rows, full.pad_cols
    for top, left in ((pr + 5, pc + 7), (pr - 4, pc + 20), (3, 2)):  # inside, across the edge, far in the pad
        part = optics(scene, crop=(top, left, 10, 12))
        ref = full.photons[..., top:top + 10, left:left + 12]
        assert part.photons.shape == ref.shape
        # the error bound is the light beyond the margin: psf_tolerance of the scene's level
        assert (part.photons - ref).abs().max() < 1e-3 * full.photons.max()
        assert part.metadata["window"] == (top, left)
    with pytest.raises(ValueError, match="crop"):
        optics(scene, crop=(0, 0, 1000, 5))
    with pytest.raises(ValueError, match="crop"):
        optics(scene, crop=(0, 0, 5))
    iso = DiffractionLimitedOptics(4.0, F, pad_mode="isetcam")
    torch.testing.assert_close(iso(scene, crop=(2, 3, 10, 12)).photons, iso(scene).photons[..., 2:12, 3:15])


@pytest.mark.parametrize("factored", [False, True])
def test_edge_padding_full_output_is_the_window_computation(factored):
    # A 0 | 1 step, f/8, 'edge' padding: the scene continues as 0 to the left and 1 to the right, so the full
    # optical image's outer columns are about 0 and 1 (the diffraction tail of the step 64 samples away: 0.006). The
    # full output was a circular FFT of the padded grid alone: the opposite border's light wrapped into its outer
    # margin (0.40, 0.24 on the left; 0.92 on the right), 0.397 away from forward(crop=) on the same samples.
    n, far = 32, 1e4
    d_i = 1 / (1 / F - 1 / far)
    x = torch.zeros(1, 1, n, n, dtype=torch.float64)
    x[..., n // 2:] = 1.0
    wave = torch.tensor([550.0], dtype=torch.float64)
    hfov = 2 * math.degrees(math.atan(n * 1e-6 / (2 * d_i)))
    scene = (Scene.from_factors(x, torch.ones(1, 1, 1, dtype=torch.float64), wave, hfov_deg=hfov, distance_m=far)
             if factored else Scene(x, wave, hfov_deg=hfov, distance_m=far))
    optics = DiffractionLimitedOptics(8.0, F, pad_mode="edge", relative_illumination=None)
    full = optics(scene).photons[0, 0]
    k = math.pi / (1 + 4 * 64 * (1 + d_i / far) ** 2)
    h, w = full.shape
    window = optics(scene, crop=(0, 0, h, w)).photons[0, 0]
    torch.testing.assert_close(full, window, rtol=0, atol=1e-9 * k)
    assert full[:, :3].max() < 0.01 * k and full[:, -3:].min() > 0.99 * k


@pytest.mark.parametrize("mode", ["edge", "mean"])
def test_uniform_scene_stays_uniform_with_edge_and_mean_padding(mode):
    x = torch.full((1, 2, 12, 14), 3e15, dtype=torch.float64)
    scene = Scene(x, torch.tensor([450.0, 650.0], dtype=torch.float64), hfov_deg=0.3, distance_m=1.2)
    oi = DiffractionLimitedOptics(8.0, F, relative_illumination=None, pad_mode=mode)(scene)
    k = geometry.camera_equation_factor(torch.tensor(8.0, dtype=torch.float64),
                                        geometry.magnification(F, 1.2)).item()
    torch.testing.assert_close(oi.photons, torch.full_like(oi.photons, 3e15 * k), rtol=1e-10, atol=0)
    zero = DiffractionLimitedOptics(8.0, F, relative_illumination=None, pad_mode="zero")(scene)
    assert zero.photons[0, 0, zero.pad_rows, zero.pad_cols] < 0.5 * 3e15 * k  # a dark border pulls the corner down


@pytest.mark.parametrize("hfov_deg", [2.0, 20.0])  # blurred; a blur below a sample (extended only)
def test_a_number_pad_mode_is_a_radiance_imaged_like_the_scenes(hfov_deg):
    """pad_mode=v is the radiance beyond the scene's edges. It was put into the irradiance buffer as it was, 1 / k of
    the scene's irradiance for that radiance: a uniform scene of radiance v padded with v came out 20.8x brighter in the
    corner and 11 % in the centre at f/4. Now it stays uniform at k T v; with cos4th (held at the edges beyond them) it
    is what 'edge' gives for a uniform scene, and a pad of 0 is 'zero'."""
    v = 1e15
    wave = torch.tensor([450.0, 650.0], dtype=torch.float64)
    scene = Scene(torch.full((1, 2, 32, 32), v, dtype=torch.float64), wave, hfov_deg=hfov_deg, distance_m=1.2)
    t = torch.tensor([0.9, 0.6], dtype=torch.float64)
    oi = DiffractionLimitedOptics(4.0, F, transmittance=t, relative_illumination=None, pad_mode=v)(scene)
    k = math.pi / (1 + 4 * 16 * (1 + F / (1.2 - F)) ** 2)  # ISETCam's camera equation, m = d_i / d_o
    expected = (k * t * v).reshape(1, 2, 1, 1).expand_as(oi.photons)
    torch.testing.assert_close(oi.photons, expected, rtol=1e-10, atol=0)
    by_number = DiffractionLimitedOptics(4.0, F, transmittance=t, pad_mode=v)(scene)
    edge = DiffractionLimitedOptics(4.0, F, transmittance=t, pad_mode="edge")(scene)
    torch.testing.assert_close(by_number.photons, edge.photons, rtol=1e-10, atol=0)
    c = edge.photons.shape[-1] // 2
    assert float(edge.photons[0, 0, 0, 0]) < (0.999 if hfov_deg == 2 else 0.95) * float(edge.photons[0, 0, c, c])
    g = torch.Generator().manual_seed(0)
    textured = Scene(v * torch.rand(1, 2, 32, 32, generator=g, dtype=torch.float64), wave, hfov_deg=hfov_deg,
                     distance_m=1.2)
    zero = DiffractionLimitedOptics(4.0, F, pad_mode="zero")(textured)
    torch.testing.assert_close(DiffractionLimitedOptics(4.0, F, pad_mode=0.0)(textured).photons, zero.photons,
                               rtol=1e-12, atol=1e-9 * float(zero.photons.max()))


def test_blur_skipped_when_psf_is_far_below_a_sample():
    g = torch.Generator().manual_seed(3)
    x = torch.rand(1, 1, 8, 8, generator=g, dtype=torch.float64)
    # lambda N = 0.55 um; samples of 1 mm: max |1 - OTF| = 4/pi * 0.55e-6 / (sqrt(2) 1e-3) = 5e-4 < 1e-3
    d_i = 1 / (1 / F - 1 / 1.2)
    hfov = 2 * math.degrees(math.atan(8 * 1e-3 / (2 * d_i)))
    scene = Scene(x, torch.tensor([550.0], dtype=torch.float64), hfov_deg=hfov, distance_m=1.2)
    fast = DiffractionLimitedOptics(1.0, F, relative_illumination=None)(scene)
    slow = DiffractionLimitedOptics(1.0, F, relative_illumination=None, blur_skip_tolerance=0.0)(scene)
    assert fast.pad_rows == 0 and fast.photons.shape == x.shape
    pr = slow.pad_rows
    core = slow.photons[..., pr:pr + 8, pr:pr + 8]
    assert (fast.photons - core).abs().max() <= 1e-3 * fast.photons.max()


def test_geometry_formulas():
    d_i = geometry.image_distance(0.05, torch.tensor(1.0, dtype=torch.float64)).item()
    assert d_i == pytest.approx(1 / 19, rel=1e-12)
    assert geometry.magnification(0.05, 0.1).item() == pytest.approx(-1.0)
    y = torch.zeros(1, 1, dtype=torch.float64)
    xs = torch.tensor([[0.0, 1.0]], dtype=torch.float64)
    c4 = geometry.cos4th(y, xs, 1.0)
    assert c4[0, 0, 0].tolist() == pytest.approx([1.0, 0.25])  # cos 45 deg ^ 4
    # ISETCam's finite-aperture formula: 1 on axis, and below cos^4 growth off axis for a fast lens
    xs2 = torch.linspace(0, 2e-3, 5, dtype=torch.float64)[None]
    fin = geometry.cos4th_isetcam(torch.zeros(1, 1, dtype=torch.float64), xs2, 4e-3, 2.0)
    assert fin[0, 0, 0, 0].item() == pytest.approx(1.0, abs=1e-12)
    assert (fin[0, 0, 0, 1:] < 1).all()
    with pytest.raises(ValueError, match="object_distance_m"):
        geometry.image_distance(torch.tensor(0.05), torch.tensor(0.01))


@pytest.mark.parametrize("f_number", [0.6, 2.0, 16.0, 64.0, 1e4])
def test_isetcam_relative_illumination_against_the_formula_in_50_digits(f_number):
    """ISETCam's finite-aperture cos4th (cos4th.m) evaluated as written in 50-digit arithmetic (mpmath), against the
    library's float32 and float64 values, on axis (exactly 1) and off axis out to 60 degrees. As written it cancels
    for a slow lens: in float32 it gave 0.5 on axis at f/32 and negative irradiance at f/64; in float64 0 at f/1e4."""
    import mpmath

    mpmath.mp.dps = 50
    d = 4e-3
    xs = [0.0, 0.3e-3, 1e-3, 2.5e-3, 6.9e-3]

    def isetcam(x):
        n, xm, dm = mpmath.mpf(f_number), mpmath.mpf(x), mpmath.mpf(d)
        sin_t = 1 / (1 + 4 * n**2)
        cos2_t = 1 - sin_t**2
        tan2_t = sin_t**2 / cos2_t
        tan2_phi = xm**2 / dm**2
        root = mpmath.sqrt(tan2_phi**2 + 2 * tan2_phi * (1 - tan2_t) + 1 / cos2_t**2)
        return float((1 - (1 - tan2_t + tan2_phi) / root) / (2 * sin_t**2))

    want = np.array([isetcam(x) for x in xs])
    assert want[0] == pytest.approx(1.0, abs=1e-40)
    for dtype, rtol in ((torch.float32, 2e-6), (torch.float64, 1e-14)):
        x = torch.tensor([xs], dtype=dtype)
        got = geometry.cos4th_isetcam(torch.zeros(1, 1, dtype=dtype), x, torch.tensor([d], dtype=dtype),
                                      torch.tensor([f_number], dtype=dtype))[0, 0, 0].double().numpy()
        np.testing.assert_allclose(got, want, rtol=rtol, atol=0)


def test_gradcheck_f_number():
    x = torch.rand(1, 2, 6, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(4)) * 1e3
    scene = Scene(x, torch.tensor([500.0, 600.0], dtype=torch.float64), hfov_deg=0.1, distance_m=1.2)

    optics = DiffractionLimitedOptics(4.0, F, margin=3, learn_f_number=True)

    def fn(n):
        return torch.func.functional_call(optics, {"f_number": n}, (scene,)).photons

    n = torch.tensor(4.0, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(fn, (n,), eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_bad_arguments():
    with pytest.raises(ValueError, match="f_number"):
        DiffractionLimitedOptics(-1.0)
    with pytest.raises(ValueError, match="pad_mode"):
        DiffractionLimitedOptics(4.0, pad_mode="reflect")
    with pytest.raises(ValueError, match="relative_illumination"):
        DiffractionLimitedOptics(4.0, relative_illumination="cos3")
    with pytest.raises(TypeError, match="scene"):
        DiffractionLimitedOptics(4.0)(torch.ones(1, 1, 4, 4))
    # a tensor that requires grad would be copied as a constant: said, not silently detached (gradient audit)
    wants_grad = torch.tensor(4.0, requires_grad=True)
    with pytest.raises(ValueError, match="f_number: got a tensor that requires grad.*learn_f_number=True"):
        DiffractionLimitedOptics(wants_grad)
    assert DiffractionLimitedOptics(wants_grad, learn_f_number=True).f_number.requires_grad
    with pytest.raises(ValueError, match="focal_length_m: got a tensor that requires grad"):
        DiffractionLimitedOptics(4.0, torch.tensor(4e-3, requires_grad=True))
    with pytest.raises(ValueError, match="transmittance: got a tensor that requires grad"):
        DiffractionLimitedOptics(4.0, transmittance=torch.tensor([0.9, 0.9], requires_grad=True),
                                 transmittance_wavelengths_nm=[400.0, 700.0])
    # the same for the wavefront's Zernike terms and a measured PSF (they were detached silently)
    from isettorch.optics import ShiftInvariantOptics, WavefrontOptics

    z = torch.zeros(6, dtype=torch.float64, requires_grad=True)
    with pytest.raises(ValueError, match="zernike_um: got a tensor that requires grad.*learn_zernike=True"):
        WavefrontOptics(z, f_number=4.0)
    assert WavefrontOptics(z, f_number=4.0, learn_zernike=True).zernike_um.requires_grad
    psf = torch.ones(5, 5, dtype=torch.float64, requires_grad=True)
    with pytest.raises(ValueError, match="psf: got a tensor that requires grad.*learn_psf=True"):
        ShiftInvariantOptics(psf, 1e-6)
    with pytest.raises(ValueError, match="psf_spacing_m: got a tensor that requires grad"):
        ShiftInvariantOptics(psf.detach(), torch.tensor(1e-6, requires_grad=True))


def test_plan_float32_and_isetcam_plan():
    g = torch.Generator().manual_seed(6)
    x = torch.rand(1, 3, 16, 20, generator=g, dtype=torch.float64) * 1e15
    scene = Scene(x, torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64), hfov_deg=0.6, distance_m=1.2)
    optics = DiffractionLimitedOptics(2.8, F)
    plan = optics.plan(scene)
    oi = optics(scene)
    assert plan["full_shape"] == tuple(oi.photons.shape[-2:]) and plan["pad"] == (oi.pad_rows, oi.pad_cols)
    torch.testing.assert_close(plan["sample_spacing_m"], oi.sample_spacing_m)
    oi32 = optics(scene.to(dtype=torch.float32))
    assert oi32.photons.dtype == torch.float32
    torch.testing.assert_close(oi32.photons.double(), oi.photons, rtol=1e-4, atol=1e-4 * oi.photons.max().item())
    iso = DiffractionLimitedOptics(2.8, F, pad_mode="isetcam")
    p2, o2 = iso.plan(scene), iso(scene)
    assert p2["full_shape"] == tuple(o2.photons.shape[-2:]) and p2["pad"] == (2, 3)
    torch.testing.assert_close(p2["sample_spacing_m"], o2.sample_spacing_m)


def test_blur_negligible_per_item_matches_the_corner_frequency_rule():
    # the blur is negligible when 1 - MTF at the grid's corner frequency sqrt(2) / (2 dx) is within the tolerance for
    # every item (Goodman 6.31); memoised per (spacing, f-number), shared memos give the same answers, one value
    # broadcasts, and mismatched per-item lengths raise
    from isettorch.optics.diffraction import dl_mtf_1d

    wl = torch.linspace(400.0, 700.0, 31, dtype=torch.float64)
    g = torch.Generator().manual_seed(4)
    a, b = DiffractionLimitedOptics(f_number=4.0), DiffractionLimitedOptics(f_number=4.0)
    b._negligible_memo = a.__dict__.setdefault("_negligible_memo", {})
    seen = set()
    for i in range(40):
        k = 1 + i % 3  # items per call
        dx = 10 ** (-5.5 + 3.0 * torch.rand(k, generator=g, dtype=torch.float64))  # 3 um to 3 mm
        n = torch.tensor([1.4, 2.0, 8.0], dtype=torch.float64)[torch.randint(0, 3, (k,), generator=g)]
        s = math.sqrt(2) / (2 * dx) * 700e-9 * n
        expected = bool((1 - dl_mtf_1d(s) <= a.blur_skip_tolerance).all())
        assert a.blur_negligible(dx, wl, n) == expected == b.blur_negligible(dx, wl, n)
        seen.add(expected)
    assert seen == {True, False}
    assert a.blur_negligible(torch.tensor([1e-3, 2e-3]), wl, torch.tensor([2.0])) == all(
        a.blur_negligible(torch.tensor([d]), wl, torch.tensor([2.0])) for d in (1e-3, 2e-3))
    with pytest.raises(ValueError, match="dx, f_number"):
        a.blur_negligible(torch.tensor([1e-3, 2e-3]), wl, torch.tensor([2.0, 4.0, 8.0]))


def test_a_psf_far_beyond_the_capped_margin_warns_of_wrap_around():
    # f/64 at 700 nm: an Airy core radius of 1.22 lambda N = 55 um over a scene 1.35 um wide (32 samples of 42 nm).
    # The margin is capped at 2 x 32 samples, so the FFT folds the blur back onto the image: a warning, not silence.
    import warnings

    p = torch.zeros(1, 1, 32, 32, dtype=torch.float64)
    p[..., :8] = 1.0
    optics = DiffractionLimitedOptics(f_number=64, relative_illumination=None)
    with pytest.warns(UserWarning, match="wraps around"):
        optics(Scene(p, torch.tensor([700.0]), hfov_deg=0.02))
    with warnings.catch_warnings():  # an ordinary field: no warning
        warnings.simplefilter("error")
        DiffractionLimitedOptics(f_number=4, relative_illumination=None)(Scene(p, torch.tensor([700.0]), hfov_deg=2.0))


def test_a_defocus_disc_beyond_the_capped_margin_warns_of_wrap_around():
    """A compact blur keeps its light inside its disc, so a margin capped short of the disc wraps a share of it far
    above psf_tolerance; the warning waited for 10x the cap (the diffraction tail's rule). A point in a 16 x 16 scene
    with a 1 um defocus at f/2 (disc 180 samples, cap 32): 26 % more light in the default window than with a margin
    that holds the disc, without a word. Now it warns; a disc within the cap does not."""
    import warnings

    from isettorch.optics import WavefrontOptics

    x = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    x[0, 0, 8, 8] = 1.0
    scene = Scene(x, torch.tensor([550.0], dtype=torch.float64), hfov_deg=0.125, distance_m=10.0)
    z = torch.zeros(5, dtype=torch.float64)
    z[4] = 1.0  # c_2^0, um
    optics = WavefrontOptics(z, f_number=2.0, focal_length_m=4e-3, relative_illumination=None)
    with pytest.warns(UserWarning, match="wraps around"):
        capped = optics(scene)
    held = WavefrontOptics(z, f_number=2.0, focal_length_m=4e-3, relative_illumination=None, margin=400)(scene)
    d = held.pad_rows - capped.pad_rows
    window = held.photons[0, 0, d:d + capped.photons.shape[-2], d:d + capped.photons.shape[-1]]
    assert float(capped.photons.sum()) > 1.2 * float(window.sum())  # what the warning is about
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        WavefrontOptics(z, f_number=2.0, focal_length_m=4e-3, relative_illumination=None, max_margin_factor=12.0)(
            scene)


def test_the_wrap_around_warning_comes_once_per_render(monkeypatch):
    """A numeric pad_mode with relative illumination blurs the scene and the fill separately; the fill's blur reused
    nothing, so the margin (and the wavefront's geometric blur radius, the Zernike coefficients and the pupil-gradient
    maximum within it) was computed again and the warning was given twice per render (under an 'always' filter)."""
    import warnings

    from isettorch.optics import WavefrontOptics

    x = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    x[0, 0, 8, 8] = 1.0
    scene = Scene(x, torch.tensor([550.0], dtype=torch.float64), hfov_deg=0.125, distance_m=10.0)
    z = torch.zeros(5, dtype=torch.float64)
    z[4] = 1.0
    optics = WavefrontOptics(z, f_number=2.0, focal_length_m=4e-3, relative_illumination="cos4th", pad_mode=0.5)
    calls = []
    core = WavefrontOptics.psf_core_m
    monkeypatch.setattr(WavefrontOptics, "psf_core_m", lambda self, *a: calls.append(1) or core(self, *a))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        optics(scene)
    assert sum("wraps around" in str(w.message) for w in caught) == 1
    assert len(calls) == 1


@pytest.mark.parametrize("n", [0.5, 2.0, 2.8, 4.0, 11.0])
def test_camera_equation_forms_are_pi_sin2_theta(n):
    """E / L = pi sin^2(theta): ISETCam's form with tan(theta) = 1 / (2 N_w), the paraxial one with sin(theta) =
    1 / (2 N_w) (Smith, ch. 9); the paraxial one is larger by 1 / (4 N_w^2) relative (6.25 % at f/2), here at
    magnification 0.5 (N_w = 1.5 N)."""
    nw = 1.5 * n
    iset = float(geometry.camera_equation_factor(n, -0.5))
    par = float(geometry.camera_equation_factor(n, -0.5, paraxial=True))
    assert iset == pytest.approx(math.pi * math.sin(math.atan(1 / (2 * nw))) ** 2, rel=1e-12)
    assert par == pytest.approx(math.pi * (1 / (2 * nw)) ** 2, rel=1e-12)
    assert par / iset - 1 == pytest.approx(1 / (4 * nw**2), rel=1e-9)


def test_a_learned_f_number_below_the_physical_limit_is_an_error():
    """An optimiser step that takes a learnable f-number below 0.5 (faster than any lens in air, the constructor's
    bound) is a clear error at the next forward, not a silently unphysical lens."""
    x = torch.rand(1, 2, 6, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(4)) * 1e3
    scene = Scene(x, torch.tensor([500.0, 600.0], dtype=torch.float64), hfov_deg=0.1, distance_m=1.2)
    optics = DiffractionLimitedOptics(0.6, F, margin=3, learn_f_number=True)
    optics(scene)
    with torch.no_grad():
        optics.f_number.fill_(0.3)
    with pytest.raises(ValueError, match=r"f_number: expected >= 0\.5 .*left the physical range"):
        optics(scene)


def test_dl_otf_refuses_a_non_positive_f_number():
    """The functional OTF, called directly, refuses N <= 0 (it returned values above 1, or 1 everywhere)."""
    from isettorch.optics.diffraction import dl_otf

    f = torch.zeros(1, 2, dtype=torch.float64)
    for n in (-2.0, 0.0):
        with pytest.raises(ValueError, match="f_number: expected positive values"):
            dl_otf(f, f, torch.tensor([500.0], dtype=torch.float64), torch.tensor([n], dtype=torch.float64))


def test_the_mtf_is_even_and_a_nan_frequency_or_bad_wavelength_is_not_hidden():
    """dl_mtf_1d of a negative normalised frequency is its mirror (it gave 1.36 > 1: acos past pi/2); a NaN
    frequency gives NaN (it gave 0, a perfect blur); dl_otf refuses NaN or non-positive wavelengths by name."""
    s = torch.tensor([0.25, 0.5, 0.9], dtype=torch.float64)
    torch.testing.assert_close(dl_mtf_1d(-s), dl_mtf_1d(s), rtol=0, atol=0)
    assert math.isnan(dl_mtf_1d(torch.tensor([math.nan], dtype=torch.float64)).item())
    for w in (math.nan, -550.0, 0.0):
        with pytest.raises(ValueError, match="wavelengths_nm: expected finite positive wavelengths"):
            dl_otf(torch.zeros(1, 2), torch.zeros(1, 2), torch.tensor([w]), torch.tensor([4.0]))


def _fov_optics(kind, ri):
    from isettorch.optics import ShiftInvariantOptics, WavefrontOptics

    kw = {} if ri else {"relative_illumination": None}
    if kind == "dl":
        return DiffractionLimitedOptics(2.8, 4e-3, **kw)
    if kind == "dl_learn":
        return DiffractionLimitedOptics(2.8, 4e-3, learn_f_number=True, **kw)
    if kind == "wavefront":
        return WavefrontOptics(torch.tensor([0.0, 0, 0, 0, 0.1]), f_number=2.8, focal_length_m=4e-3, **kw)
    psf = torch.exp(-(torch.arange(-4.0, 5.0)[:, None] ** 2 + torch.arange(-4.0, 5.0) ** 2) / 4)
    return ShiftInvariantOptics(psf, 1e-6, f_number=2.8, focal_length_m=4e-3, **kw)


@pytest.mark.parametrize("kind", ["dl", "dl_learn", "wavefront", "psf"])
@pytest.mark.parametrize("what", ["hfov_deg", "distance_m"])
@pytest.mark.parametrize("ri", [True, False])
def test_gradient_to_the_scene_field_of_view_and_distance_includes_the_blur(kind, what, ri):
    # The sample spacing, hence the OTF's frequencies, depends on the scene's field of view and distance. A cached,
    # detached OTF dropped the blur's term (d sum(photons^2) / d hfov -2.4e-4 for +0.495; without relative
    # illumination no gradient at all), and dl_otf's sqrt at DC made it NaN with a learnable f-number. Autograd
    # against central differences (torch.autograd.gradcheck), float64.
    x = torch.rand(1, 2, 12, 12, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    wave = torch.tensor([450.0, 650.0], dtype=torch.float64)
    optics = _fov_optics(kind, ri)
    fixed = {"hfov_deg": torch.tensor([0.5], dtype=torch.float64),
             "distance_m": torch.tensor([1.0], dtype=torch.float64)}

    def fn(v):  # a scalar: a failing gradcheck's full Jacobian would take a backward pass per output sample
        return (optics(Scene(x, wave, **{**fixed, what: v})).photons ** 2).sum()

    v = fixed[what].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(fn, (v,), eps=1e-7, atol=1e-8, rtol=1e-5, fast_mode=True)
