"""User-PSF optics, PSF/LSF/MTF/encircled-energy analysis and plots, photometric camera equation."""

import math

import numpy as np
import pytest
import torch
from scipy import special

from isettorch import Scene, spectral
from isettorch.optics import DiffractionLimitedOptics, ShiftInvariantOptics, analysis

F = 4e-3


def _gauss(sigma_m, spacing_m, half=16):
    k = torch.arange(-half, half + 1, dtype=torch.float64) * spacing_m
    return torch.exp(-(k[:, None] ** 2 + k[None, :] ** 2) / (2 * sigma_m**2))


def _scene_with_spacing(x, wave, dx, distance=1.2):
    d_i = 1 / (1 / F - 1 / distance)
    hfov = 2 * math.degrees(math.atan(x.shape[-1] * dx / (2 * d_i)))
    return Scene(x, torch.tensor(wave, dtype=torch.float64), hfov_deg=hfov, distance_m=distance)


def test_gaussian_psf_is_resampled_exactly():
    sigma, dx = 2e-6, 1e-6
    optics = ShiftInvariantOptics(_gauss(sigma, 0.5e-6, half=24), psf_spacing_m=0.5e-6, f_number=4.0, focal_length_m=F,
                                  relative_illumination=None)
    x = torch.zeros(1, 1, 24, 24, dtype=torch.float64)
    x[..., 12, 3] = 1.0  # near the left edge
    oi = optics(_scene_with_spacing(x, [550.0], dx))
    pr, pc = oi.pad_rows, oi.pad_cols
    out = oi.photons[0, 0] / oi.photons.sum()
    yy, xx = np.mgrid[:out.shape[0], :out.shape[1]]
    ref = np.exp(-((yy - pr - 12) ** 2 + (xx - pc - 3) ** 2) * dx**2 / (2 * sigma**2))
    ref /= ref.sum()
    assert np.abs(out.numpy() - ref).max() < 1e-6 * ref.max() + 1e-12
    assert out[:, pc + 20:].abs().max() < 1e-9 * ref.max()  # the opposite edge: nothing wraps around
    assert pc >= 12  # the margin covers the PSF's half width (12 um = 12 samples)


def test_otf_cache_follows_the_psf_spacing():
    # a new psf_spacing_m is a new PSF size: the cache (keyed on the PSF tensor alone) blurred as before
    x = torch.zeros(1, 1, 24, 24, dtype=torch.float64)
    x[..., 12, 12] = 1.0
    scene = _scene_with_spacing(x, [550.0], 1e-6)
    optics = ShiftInvariantOptics(_gauss(1e-6, 0.25e-6), psf_spacing_m=0.25e-6, f_number=4.0, focal_length_m=F,
                                  margin=20)
    optics(scene)
    optics.psf_spacing_m = torch.tensor([0.5e-6], dtype=torch.float64)
    fresh = ShiftInvariantOptics(_gauss(1e-6, 0.25e-6), psf_spacing_m=0.5e-6, f_number=4.0, focal_length_m=F,
                                 margin=20)
    torch.testing.assert_close(optics(scene).photons, fresh(scene).photons, rtol=1e-12, atol=0)


def test_psf_wavelength_interpolation_and_range():
    psfs = torch.stack([_gauss(1e-6, 0.5e-6), _gauss(3e-6, 0.5e-6)])
    optics = ShiftInvariantOptics(psfs, 0.5e-6, psf_wavelengths_nm=[450.0, 650.0], f_number=4.0, focal_length_m=F)
    f = torch.tensor([[0.0, 5e4, 1e5]], dtype=torch.float64)
    z = torch.zeros(1, 1, dtype=torch.float64)
    n = torch.tensor([4.0], dtype=torch.float64)
    o = optics.otf(z, f, torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64), n)[0, :, 0]
    torch.testing.assert_close(o[1], 0.5 * (o[0] + o[2]))
    # a sampled Gaussian's transfer function is the Gaussian exp(-2 pi^2 sigma^2 f^2)
    torch.testing.assert_close(o[0].real, torch.exp(-2 * math.pi**2 * 1e-12 * f[0] ** 2), rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="wavelengths_nm"):
        optics.otf(z, f, torch.tensor([400.0], dtype=torch.float64), n)
    with pytest.raises(ValueError, match="psf"):
        ShiftInvariantOptics(-psfs, 0.5e-6, psf_wavelengths_nm=[450.0, 650.0])


def test_analysis_against_analytic_diffraction():
    dl = DiffractionLimitedOptics(4.0, F)
    lam_n = 550e-9 * 4.0
    f = torch.linspace(0, 1.2 / lam_n, 25, dtype=torch.float64)
    s = np.minimum(f.numpy() * lam_n, 1)
    ref = 2 / np.pi * (np.arccos(s) - s * np.sqrt(1 - s * s))
    got = analysis.mtf(dl, [550.0], f)[0, 0].numpy()
    assert np.abs(got - ref).max() < 1e-12
    torch.testing.assert_close(analysis.mtf(dl, [550.0], f, axis="y"), analysis.mtf(dl, [550.0], f))
    # encircled energy of the Airy pattern: 1 - J0^2(x) - J1^2(x), x = pi r / (lambda N) (Rayleigh)
    dx = lam_n / 8
    p = analysis.psf(dl, [550.0], dx, 256)[0, 0]
    radii = np.array([0.5, 1.0, 1.2197, 2.2331]) * lam_n
    ee = analysis.encircled_energy(p, dx, torch.from_numpy(radii))
    x = np.pi * radii / lam_n
    ref_ee = 1 - special.j0(x) ** 2 - special.j1(x) ** 2
    np.testing.assert_allclose(ee.numpy(), ref_ee, atol=1e-2)
    assert ee[2].item() == pytest.approx(0.8378, rel=5e-3)
    # LSF: unit sum, symmetric, and the Airy pattern integrated along y in closed form, L(x) ~ H1(2v) / v^2 with
    # v = pi x / (lambda N) (Struve H1; limit 8 / (3 pi) at 0), to 5e-3 of its peak out to 5 lambda N; FWHM 1.0017
    # lambda N (the closed form's half-maximum)
    line = analysis.lsf(dl, [550.0], dx, 512)[0, 0]
    assert line.sum().item() == pytest.approx(1.0, rel=1e-12)
    torch.testing.assert_close(line[1:], line[1:].flip(0))
    v = np.pi * np.arange(1, 41) / 8
    ref_lsf = np.concatenate([[8 / (3 * np.pi)], special.struve(1, 2 * v) / v**2]) / (8 / (3 * np.pi))
    got_lsf = line.numpy()[256:297] / line[256].item()
    np.testing.assert_allclose(got_lsf, ref_lsf, rtol=0, atol=5e-3)
    j = int(np.argmax(got_lsf < 0.5))
    half = j - 1 + (got_lsf[j - 1] - 0.5) / (got_lsf[j - 1] - got_lsf[j])
    assert 2 * half / 8 == pytest.approx(1.0017, rel=5e-3)


def test_plots_save_png(tmp_path):
    import matplotlib.pyplot as plt

    dl = DiffractionLimitedOptics(2.8, F)
    figs = {
        "psf": analysis.plot_psf(dl, 550.0, size=32),
        "lsf": analysis.plot_lsf(dl, size=64),
        "mtf": analysis.plot_mtf(dl),
        "ee": analysis.plot_encircled_energy(dl, size=32),
    }
    for name, fig in figs.items():
        path = tmp_path / f"{name}.png"
        fig.savefig(path)
        assert path.stat().st_size > 1000
        plt.close(fig)


def test_photometric_camera_equation_and_to():
    # uniform scene of luminance Lv: on-axis illuminance = pi Lv T / (1 + 4 N^2 (1 + |m|)^2)
    w = spectral.default_wavelengths(dtype=torch.float64)
    spd = spectral.energy_to_photons(spectral.illuminant("D65", w), w, dim=0)
    x = spd[None, :, None, None].expand(1, -1, 6, 6).clone()
    scene = Scene(x, w, hfov_deg=1.0, distance_m=1.2).set_mean_luminance(100.0)
    t = torch.full((31,), 0.9, dtype=torch.float64)
    oi = DiffractionLimitedOptics(4.0, F, transmittance=t, relative_illumination=None, pad_mode="edge")(scene)
    m = (1 / (1 / F - 1 / 1.2)) / 1.2
    expected = math.pi * 100.0 * 0.9 / (1 + 4 * 16 * (1 + m) ** 2)
    assert oi.illuminance()[0, 0, 3, 3].item() == pytest.approx(expected, rel=1e-9)
    o32 = oi.to(dtype=torch.float32)
    assert o32.photons.dtype == torch.float32 and o32.sample_spacing_m.dtype == torch.float32
    # transmittance on its own wavelength grid is resampled to the scene's
    opt2 = DiffractionLimitedOptics(4.0, F, transmittance=[0.5, 1.0], transmittance_wavelengths_nm=[400.0, 700.0])
    torch.testing.assert_close(opt2.transmittance_on(w), 0.5 + 0.5 * (w - 400) / 300)


@pytest.mark.parametrize("tol", [1e-2, 1e-3])
def test_margin_rule_bounds_the_line_spread_tail(tol):
    # the padding margin 2 lambda N / (pi^3 tol) leaves at most tol of the line-spread energy beyond it
    dl = DiffractionLimitedOptics(4.0, F, psf_tolerance=tol)
    lam_n = 650e-9 * 4.0
    margin = dl.psf_margin_m(torch.tensor([450.0, 650.0], dtype=torch.float64),
                             torch.tensor([4.0], dtype=torch.float64)).item()
    dx = lam_n / 8
    size = 2 * int(8 * margin / dx)
    line = analysis.lsf(dl, [650.0], dx, size)[0, 0]
    x = (torch.arange(size, dtype=torch.float64) - size // 2) * dx
    tail = line[x > margin].sum().item()
    assert tol / 2 < tail <= tol * 1.02


def test_analysis_helpers_refuse_bad_grids():
    from isettorch.optics import defocus_diopters_to_zernike_um
    from isettorch.optics.formats import field_of_view_deg, focal_length_for_fov_mm

    optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=F)
    w = [550.0]
    for bad in (0.0, -1e-6, float("nan")):  # (NaN, NaN and a mirrored curve)
        with pytest.raises(ValueError, match="spacing_m"):
            analysis.psf(optics, w, bad)
        with pytest.raises(ValueError, match="spacing_m"):
            analysis.lsf(optics, w, bad)
    for bad in (2.5, 0, 1):  # (torch's fftfreq TypeError, a ZeroDivisionError)
        with pytest.raises(ValueError, match="size"):
            analysis.lsf(optics, w, 1e-6, size=bad)
    img = torch.ones(1, 5, 5, dtype=torch.float64)
    with pytest.raises(ValueError, match="spacing_m"):  # (1 at every radius)
        analysis.encircled_energy(img, 0.0, [1e-6])
    with pytest.raises(ValueError, match="radii_m"):  # (0)
        analysis.encircled_energy(img, 1e-6, [-1e-6])
    # a one-value tensor spacing (an optical image's sample_spacing_m) is a spacing
    assert analysis.lsf(optics, w, torch.tensor([1e-6]), size=8).shape == (1, 1, 8)
    with pytest.raises(ValueError, match="pupil_diameter_m"):  # (-3 mm gave the 3 mm pupil's value)
        defocus_diopters_to_zernike_um(1.0, -3e-3)
    with pytest.raises(ValueError, match="along"):  # (a bare KeyError)
        focal_length_for_fov_mm("APS-C", 60.0, along="diag")
    with pytest.raises(ValueError, match="focal_length_mm"):  # (NaN)
        field_of_view_deg("APS-C", float("nan"))


def test_psf_at_a_coarse_spacing_is_band_limited_and_oversample_gives_point_samples():
    """At 1.5 lambda N the DFT grid holds only the OTF's base band: analysis.psf returned the band-limited PSF (peak
    0.68 of the sum, negative lobes) under a docstring that said 'sampled at spacing_m'. The docstring now says so,
    and oversample=4 gives the point samples of the Airy pattern (2 J1(v) / v)^2 (scipy), normalised to sum 1."""
    n_f, lam = 4.0, 550e-9
    dl = DiffractionLimitedOptics(n_f, 4e-3)
    dx, size = 1.5 * lam * n_f, 64
    k = (np.arange(size) - size // 2) * dx
    v = math.pi * np.hypot(k[:, None], k[None, :]) / (lam * n_f)
    airy = np.where(v == 0, 1.0, (2 * special.j1(np.where(v == 0, 1.0, v)) / np.where(v == 0, 1.0, v)) ** 2)
    airy /= airy.sum()
    band = analysis.psf(dl, [550.0], dx, size, oversample=1)[0, 0].numpy()
    assert band.max() < 0.75 * airy.max() and band.min() < 0  # the band-limited PSF
    point = analysis.psf(dl, [550.0], dx, size, oversample=4)[0, 0].numpy()
    assert np.abs(point - airy).max() < 2e-3 * airy.max()
    with pytest.raises(ValueError, match="^oversample: expected an integer >= 1"):
        analysis.psf(dl, [550.0], dx, size, oversample=0)
