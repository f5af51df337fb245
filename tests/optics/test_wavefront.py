"""Wavefront (Zernike) optics against the diffraction limit, a direct Fraunhofer integral, ray optics, gradcheck."""

import math

import numpy as np
import pytest
import torch
from scipy import integrate, special

from isettorch import Scene
from isettorch.optics import (
    DiffractionLimitedOptics,
    WavefrontOptics,
    analysis,
    defocus_diopters_to_zernike_um,
    zernike_basis,
    zernike_nm,
)

LAM, N, F = 550e-9, 4.0, 4e-3
LAM_N = LAM * N


def test_zernike_indexing_and_orthonormality():
    # ANSI Z80.28 / OSA single index order
    assert [zernike_nm(j) for j in range(10)] == [(0, 0), (1, -1), (1, 1), (2, -2), (2, 0), (2, 2), (3, -3),
                                                  (3, -1), (3, 1), (3, 3)]
    assert zernike_nm(12) == (4, 0)  # primary spherical
    u = (torch.arange(300, dtype=torch.float64) + 0.5) / 150 - 1
    yy, xx = torch.meshgrid(u, u, indexing="ij")
    rho, th = torch.sqrt(xx**2 + yy**2), torch.atan2(yy, xx)
    inside = rho <= 1
    z = zernike_basis(15, rho, th)[:, inside]
    gram = z @ z.T / inside.sum()
    torch.testing.assert_close(gram, torch.eye(15, dtype=torch.float64), atol=2e-2, rtol=0)
    # defocus Z_2^0 = sqrt(3)(2 rho^2 - 1)
    torch.testing.assert_close(zernike_basis(5, rho, th)[4], math.sqrt(3) * (2 * rho**2 - 1))


def test_defocus_conversion():
    # 1 D over a 6 mm pupil: c = D r^2 / (4 sqrt 3) = 9 / (4 sqrt 3) um (Thibos 2004)
    assert float(defocus_diopters_to_zernike_um(1.0, 6e-3)) == pytest.approx(9 / (4 * math.sqrt(3)), rel=1e-12)


def test_zero_coefficients_match_diffraction_limit():
    wf = WavefrontOptics(torch.zeros(15), f_number=N, focal_length_m=F, pupil_samples=64)
    dl = DiffractionLimitedOptics(N, F)
    dx = LAM_N / 4
    for w in ([450.0, 550.0, 650.0],):
        a = analysis.psf(wf, w, dx, 96)
        b = analysis.psf(dl, w, dx, 96)
        assert ((a - b).abs().amax(dim=(-2, -1)) / b.amax(dim=(-2, -1))).max() < 1e-3


@pytest.mark.parametrize("dense", [True, False])
def test_zero_coefficients_match_diffraction_limit_at_a_finite_distance(dense):
    # Both blurs are the pupil's, so a lens focused at 12 mm (d_i = 1.5 f) works at 1.5 N in both (Goodman 6.3.2);
    # the same in a factored scene's Fourier-domain path (dense False) as in the dense one.
    torch.manual_seed(0)
    wave = torch.tensor([450.0, 650.0], dtype=torch.float64)
    maps = torch.rand(1, 2, 40, 40, dtype=torch.float64)
    spectra = torch.tensor([[[1.0, 0.3], [0.2, 1.0]]], dtype=torch.float64)
    scene = Scene.from_factors(maps, spectra, wave, hfov_deg=1.0, distance_m=12e-3)
    if dense:
        scene = Scene(scene.photons, wave, hfov_deg=1.0, distance_m=12e-3)
    wf = WavefrontOptics(torch.zeros(15), f_number=N, focal_length_m=F, pupil_samples=64,
                         relative_illumination=None)
    dl = DiffractionLimitedOptics(N, F, relative_illumination=None)
    wider = DiffractionLimitedOptics(1.5 * N, F, relative_illumination=None)  # the working f-number, far away
    a, b = wf(scene).photons, dl(scene).photons
    assert ((a - b).abs().max() / b.max()).item() < 2e-3
    # far away, on the same image-plane grid (the field 1.5 times as wide at d_i = f): the same blur, up to the
    # camera equation's constant factor
    far = Scene(scene.photons, wave, hfov_deg=2 * math.degrees(math.atan(1.5 * math.tan(math.radians(0.5)))),
                distance_m=1e9)
    oc = wider(far)
    torch.testing.assert_close(oc.sample_spacing_m, dl(scene).sample_spacing_m, rtol=1e-8, atol=0)
    c = oc.photons * (b.sum() / oc.photons.sum())
    assert ((b - c).abs().max() / b.max()).item() < 1e-6


def _fraunhofer_profile(c4_um, r_m):
    """Independent reference: PSF(r) / PSF_DL(0) = |int_0^1 exp(i 2 pi W / lambda) J0(pi r rho / (lambda N)) 2 rho
    d rho|^2 for the rotationally symmetric pupil with W = c4 sqrt(3)(2 rho^2 - 1) (Born & Wolf 8.8)."""
    rho = np.linspace(0, 1, 8001)
    ph = np.exp(1j * 2 * np.pi * c4_um * np.sqrt(3) * (2 * rho**2 - 1) / (LAM * 1e6))
    return np.array([abs(integrate.simpson(ph * special.j0(np.pi * r * rho / LAM_N) * 2 * rho, x=rho)) ** 2
                     for r in r_m])


@pytest.mark.parametrize("diopters", [1.5, 4.0])
def test_defocus_psf_matches_fraunhofer_integral(diopters):
    wf = WavefrontOptics(None, f_number=N, focal_length_m=F, defocus_diopters=diopters, pupil_samples=64)
    c4 = float(defocus_diopters_to_zernike_um(diopters, F / N))
    dx = LAM_N / 4
    p = analysis.psf(wf, [550.0], dx, 128)[0, 0]
    dl_peak = (math.pi / 4) * (dx / LAM_N) ** 2  # sampled Airy peak of a unit-sum PSF
    got = (p[64, 64:] / dl_peak).numpy()
    ref = _fraunhofer_profile(c4, np.arange(64) * dx)
    assert np.abs(got - ref).max() < 2e-3  # relative to the diffraction-limited peak; measured ~5e-4
    assert ref[0] < 0.8  # the defocus is not negligible


def test_tilt_moves_the_psf_by_the_ray_aberration():
    c_um = 0.1  # OSA j = 1: W = c 2 rho sin(theta) -> transverse shift 2 c d / R = 4 c N along +rows
    wf = WavefrontOptics(torch.tensor([0.0, c_um]), f_number=N, focal_length_m=F)
    f = torch.tensor([[0.1, 0.2]], dtype=torch.float64) / LAM_N
    otf = wf.otf(f, torch.zeros(1, 1, dtype=torch.float64), torch.tensor([550.0], dtype=torch.float64),
                 torch.tensor([N], dtype=torch.float64))[0, 0, :, 0]
    shift = -torch.angle(otf) / (2 * math.pi * f[0])
    torch.testing.assert_close(shift, torch.full_like(shift, 4 * c_um * 1e-6 * N), rtol=1e-2, atol=0)


def _small_scene():
    g = torch.Generator().manual_seed(5)
    x = torch.rand(1, 1, 6, 6, generator=g, dtype=torch.float64)
    d_i = 1 / (1 / F - 1 / 1.2)
    hfov = 2 * math.degrees(math.atan(6 * LAM_N / 2 / (2 * d_i)))  # samples of lambda N / 2
    return Scene(x, torch.tensor([550.0], dtype=torch.float64), hfov_deg=hfov, distance_m=1.2)


def test_gradcheck_zernike_and_f_number():
    scene = _small_scene()
    wf = WavefrontOptics(torch.zeros(6), f_number=N, focal_length_m=F, pupil_samples=16, margin=2,
                         learn_zernike=True, learn_f_number=True)

    def fn(z, n):
        return torch.func.functional_call(wf, {"zernike_um": z, "f_number": n}, (scene,)).photons

    z = torch.tensor([0.0, 0.02, -0.03, 0.05, 0.08, -0.04], dtype=torch.float64, requires_grad=True)
    n = torch.tensor(N, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(fn, (z, n), eps=1e-7, atol=1e-7, rtol=1e-3, fast_mode=True)
    # the parameters really are learnable: a loss moves them
    wf(scene).photons.sum().backward()
    assert wf.zernike_um.grad is not None and wf.f_number.grad is not None


def test_batched_coefficients_equal_one_at_a_time():
    scene = _small_scene()
    both = Scene.cat([scene, scene])
    z = torch.tensor([[0, 0, 0, 0, 0.05], [0, 0.03, 0, 0, -0.1]], dtype=torch.float64)
    out = WavefrontOptics(z, f_number=torch.tensor([4.0, 5.6], dtype=torch.float64), focal_length_m=F,
                          pupil_samples=16, margin=4)(both)
    for i, n in enumerate([4.0, 5.6]):
        one = WavefrontOptics(z[i], f_number=n, focal_length_m=F, pupil_samples=16, margin=4)(scene)
        torch.testing.assert_close(out.photons[i:i + 1], one.photons, rtol=1e-10, atol=1e-14)


def test_bad_arguments():
    with pytest.raises(ValueError, match="pupil_samples"):
        WavefrontOptics(None, pupil_samples=7)
    with pytest.raises(ValueError, match="f_number / pupil_diameter_m"):
        WavefrontOptics(None, f_number=4.0, pupil_diameter_m=1e-3)
    with pytest.raises(ValueError, match="zernike_um"):
        WavefrontOptics(torch.full((3,), float("nan")))
    with pytest.raises(ValueError, match="j"):
        zernike_nm(-1)


def test_a_defocus_of_another_batch_is_named():
    """A [2] defocus on a batch of 1 (or a 2-D one) failed deep in the pupil with "shape '[10, 60, 31, 2]' is
    invalid"; the error names defocus_diopters and the batch."""
    from isettorch import scene as scenes

    s = scenes.macbeth(patch_size=4)
    with pytest.raises(ValueError, match=r"defocus_diopters: expected 1 or 1 values \(one per batch sample\), got 2"):
        WavefrontOptics(f_number=4.0, defocus_diopters=torch.tensor([1.0, 2.0]))(s)
    with pytest.raises(ValueError, match="defocus_diopters: expected a finite scalar or"):
        WavefrontOptics(f_number=4.0, defocus_diopters=torch.tensor([[1.0]]))


def test_zernike_indices_are_whole_numbers():
    """zernike_nm(2.5) and (True) were taken; zernike_basis(0) failed in torch.stack with an empty list."""
    from isettorch.optics.wavefront import zernike_basis, zernike_nm

    assert zernike_nm(4) == (2, 0)  # defocus (OSA/ANSI)
    for j in (2.5, True, -1):
        with pytest.raises(ValueError, match="j: expected a non-negative integer"):
            zernike_nm(j)
    with pytest.raises(ValueError, match="num: expected a number of terms >= 1"):
        zernike_basis(0, torch.zeros(2), torch.zeros(2))


def _line_spread(optics, dx, width=400, lam_nm=550.0):
    """The optics' line spread (normalised to sum 1) across a vertical line, sampled at ``dx``."""
    d_i = 1 / (1 / F - 1 / 1.2)
    hfov = 2 * math.degrees(math.atan(width * dx / (2 * d_i)))
    x = torch.zeros(1, 1, 8, width, dtype=torch.float64)
    x[..., width // 2] = 1.0
    oi = optics(Scene(x, torch.tensor([lam_nm], dtype=torch.float64), hfov_deg=hfov, distance_m=1.2))
    row = oi.photons[0, 0, oi.pad_rows + 4].numpy()
    c0 = oi.pad_cols + width // 2
    return row[c0 - 190:c0 + 191] / row.sum()


def test_aberrated_line_spread_has_no_ghost_copies():
    # An independent reference: |FFT|^2 of a 256-sample pupil (defocus c_2^0 = 0.5 um, f/2, 550 nm) zero-padded
    # to 2048, i.e. the PSF at lambda N / 8 over a 256 lambda N window, summed along one axis and taken at
    # lambda N / 2. The OTF interpolated from a 64-sample pupil (0.2 waves between samples) replicated the PSF
    # every 64 lambda N: 3.7 % of the light beyond 45 samples (truth 0.7 %), L1 error 0.050.
    n_f, c_um, lam = 2.0, 0.5, 550e-9
    dx = lam * n_f / 2
    p, m = 256, 2048
    u = (np.arange(p) + 0.5) * 2 / p - 1
    r2 = u[None, :] ** 2 + u[:, None] ** 2
    pupil = (r2 <= 1) * np.exp(2j * np.pi * c_um * math.sqrt(3) * (2 * r2 - 1) / (lam * 1e6))
    lsf = np.fft.fftshift((np.abs(np.fft.fft2(pupil, s=(m, m))) ** 2).sum(0))[::4]
    ref = lsf / lsf.sum()
    ref = ref[len(ref) // 2 - 190:len(ref) // 2 + 191]
    wf = WavefrontOptics(torch.tensor([0, 0, 0, 0, c_um]), f_number=n_f, focal_length_m=F, pad_mode="edge",
                         margin=200)
    got = _line_spread(wf, dx)
    far = np.abs(np.arange(381) - 190) >= 45
    assert abs(got[far].sum() - ref[far].sum()) < 0.002
    assert np.abs(got - ref).sum() < 0.012
    # the criterion refines the grid (64 -> 128 samples here); a fixed coarse grid is what it replaces
    coarse = _line_spread(WavefrontOptics(torch.tensor([0, 0, 0, 0, c_um]), f_number=n_f, focal_length_m=F,
                                          pad_mode="edge", margin=200, max_pupil_samples=64, max_step_waves=0.25), dx)
    assert np.abs(coarse - ref).sum() > 0.04


@pytest.mark.filterwarnings("ignore:optics. the PSF reaches")  # a 6-sample scene under a 0.6 um defocus: it wraps
def test_refined_grid_per_item_and_bad_refinement_arguments():
    # a batch whose items need different pupil grids equals the items one at a time
    z = torch.tensor([[0, 0, 0, 0, 0.0], [0, 0, 0, 0, 0.6]], dtype=torch.float64)
    wf = WavefrontOptics(z, f_number=2.0, focal_length_m=F)
    assert wf._samples_for(z, torch.tensor([550.0], dtype=torch.float64)) == [64, 256]
    scene = _small_scene()
    both = wf(Scene.cat([scene, scene]))
    for i in range(2):
        one = WavefrontOptics(z[i], f_number=2.0, focal_length_m=F)(scene)
        torch.testing.assert_close(both.photons[i:i + 1], one.photons, rtol=1e-10, atol=1e-14)
    for bad in (32, 101):  # below pupil_samples; odd (101 gave a 102-sample grid)
        with pytest.raises(ValueError, match="max_pupil_samples"):
            WavefrontOptics(None, pupil_samples=64, max_pupil_samples=bad)
    with pytest.raises(ValueError, match="max_step_waves"):
        WavefrontOptics(None, max_step_waves=0.5)
    with pytest.warns(UserWarning, match="max_pupil_samples"):
        WavefrontOptics(torch.tensor([0, 0, 0, 0, 3.0]), f_number=2.0, focal_length_m=F, max_pupil_samples=64)(
            scene)


def test_otf_cache_follows_the_focal_length():
    # defocus in diopters becomes um through the pupil diameter f / N: a new focal length is a new OTF (the cache
    # kept the first one: peak 0.0055 for 0.0008 at 8 mm)
    def scene(f_m):  # the same image-plane sampling (1 um) at either focal length
        d_i = 1 / (1 / f_m - 1 / 1.2)
        x = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
        x[..., 8, 8] = 1.0
        return Scene(x, torch.tensor([550.0], dtype=torch.float64), distance_m=1.2,
                     hfov_deg=2 * math.degrees(math.atan(16 * 1e-6 / (2 * d_i))))

    wf = WavefrontOptics(None, f_number=4.0, focal_length_m=4e-3, defocus_diopters=5.0, margin=8)
    wf(scene(4e-3))
    wf.focal_length_m = torch.tensor(8e-3, dtype=torch.float64)
    fresh = WavefrontOptics(None, f_number=4.0, focal_length_m=8e-3, defocus_diopters=5.0, margin=8)
    torch.testing.assert_close(wf(scene(8e-3)).photons, fresh(scene(8e-3)).photons, rtol=1e-12, atol=0)


def test_analysis_of_per_item_zernike_rows_is_each_rows_own():
    # Zernike rows [2, J] beside one f-number: psf / mtf / lsf took the batch from the f-number (1) and were refused
    # ('zernike_um: expected 1 or 1 rows'); each item is now the optics of its own row.
    from isettorch.optics import analysis

    rows = torch.tensor([[0, 0, 0, 0, 0.0], [0, 0, 0, 0, 0.2]])
    both = WavefrontOptics(rows, f_number=4.0, focal_length_m=4e-3)
    for fn, args in ((analysis.psf, ([550.0], 0.5e-6, 32)), (analysis.mtf, ([550.0], [0.0, 1e5, 2e5])),
                     (analysis.lsf, ([550.0], 0.5e-6, 64))):
        got = fn(both, *args)
        assert got.shape[0] == 2
        for i in range(2):
            one = WavefrontOptics(rows[i], f_number=4.0, focal_length_m=4e-3)
            torch.testing.assert_close(got[i:i + 1], fn(one, *args), rtol=1e-10, atol=1e-12)
