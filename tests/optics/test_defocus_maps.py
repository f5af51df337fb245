"""Depth-aware blur of scene layers by the optics (WavefrontOptics.defocus_maps): a layer off the focus plane is
blurred by the optics' PSF at that extra defocus (a uniform blur circle of geometric optics when the defocus is
large), energy is conserved, and the result is that of the same lens built with the defocus."""

import pytest
import torch

from isettorch.optics import WavefrontOptics
from isettorch.optics.analysis import psf
from isettorch.optics.blur import convolve_psf


def _point(n: int, dtype=torch.float64) -> torch.Tensor:
    x = torch.zeros(1, n, n, dtype=dtype)
    x[0, n // 2, n // 2] = 1.0
    return x


def test_large_defocus_is_the_geometric_blur_circle():
    """Thin lens, small angles: an object defocus D (diopters) images as a uniform disc of radius f^2 D / (2 N)
    on the sensor (blur diameter = pupil diameter x f x D, geometric optics; Smith, Modern Optical Engineering,
    ch. 6), so the encircled energy within r <= R is (r / R)^2."""
    f, n_f, d = 4e-3, 2.0, 8.0
    optics = WavefrontOptics(f_number=n_f, focal_length_m=f, pupil_samples=128)
    n, pitch = 129, 1.0e-6
    y = optics.defocus_maps(_point(n), pitch, d, psf_size=n)[0]
    yy, xx = torch.meshgrid(torch.arange(n) - n // 2, torch.arange(n) - n // 2, indexing="ij")
    r = torch.sqrt((xx**2 + yy**2).double()) * pitch
    radius = f**2 * d / (2 * n_f)  # 32 um
    for frac in (0.5, 0.7):
        assert float(y[r <= frac * radius].sum()) == pytest.approx(frac**2, abs=0.03)  # diffraction edge: ~2 %
    assert float(y[r <= radius].sum()) > 0.9
    assert float(y.min()) >= 0.0


def test_energy_is_conserved_and_more_defocus_blurs_more():
    """Sampled finer than the diffraction cutoff (0.5 um < lambda N / 2 = 0.55 um), the PSF is non-negative and
    sums to 1: the blurred point keeps its energy."""
    optics = WavefrontOptics(f_number=2.0, focal_length_m=4e-3)
    x = _point(129, torch.float32)
    peaks = []
    for d in (0.5, 1.0, 2.0):
        y = optics.defocus_maps(x, 0.5e-6, d, psf_size=65)
        assert y.dtype == torch.float32 and y.shape == x.shape
        assert float(y.sum()) == pytest.approx(1.0, abs=1e-5)  # the point is far from the edge
        peaks.append(float(y.max()))
    assert peaks[0] > peaks[1] > peaks[2]


def test_extra_defocus_adds_to_the_lens_own():
    """A layer ``d`` diopters off the focus of a lens with its own defocus ``d0`` is blurred as by the lens built
    with defocus ``d0 + d`` (its PSF from the OTF, convolved with reflected borders)."""
    maps = torch.rand(3, 24, 20, generator=torch.Generator().manual_seed(0))
    own = WavefrontOptics(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.02]), f_number=2.8, focal_length_m=5e-3,
                          defocus_diopters=0.5)
    built = WavefrontOptics(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.02]), f_number=2.8, focal_length_m=5e-3,
                            defocus_diopters=1.5)
    kernel = psf(built, torch.tensor([550.0], dtype=torch.float64), 2e-6, 33)[0, 0]
    torch.testing.assert_close(own.defocus_maps(maps, 2e-6, 1.0), convolve_psf(maps, kernel.float()), rtol=0,
                               atol=1e-6)


def test_bad_arguments_are_named():
    optics = WavefrontOptics(f_number=2.0, focal_length_m=4e-3)
    x = _point(16, torch.float32)
    with pytest.raises(ValueError, match="psf_size"):
        optics.defocus_maps(x, 1e-6, 1.0, psf_size=32)
    with pytest.raises(ValueError, match="spacing_m"):
        optics.defocus_maps(x, 0.0, 1.0)
    with pytest.raises(ValueError, match="defocus_diopters"):
        optics.defocus_maps(x, 1e-6, float("nan"))
    # numpy scalars and a one-value tensor are diopters too, the tensor's gradient kept
    import numpy as np

    ref = optics.defocus_maps(x, 1e-6, 1.0)
    torch.testing.assert_close(optics.defocus_maps(x, 1e-6, np.float32(1.0)), ref)
    d = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    out = optics.defocus_maps(x.double(), 1e-6, d)
    torch.testing.assert_close(out.float(), ref, rtol=0, atol=1e-6)
    (g,) = torch.autograd.grad((out * torch.rand(out.shape, generator=torch.Generator().manual_seed(0),
                                                 dtype=out.dtype)).sum(), d)
    assert torch.isfinite(g) and float(g) != 0.0


def test_the_default_window_holds_a_large_blur():
    """The PSF from the OTF repeats every psf_size samples: with the default 33 samples of 0.5 um a 5-diopter blur
    (geometric disc of radius 20 um at f/2, 4 mm) wrapped around (30 % of the light within 5 um, where the disc holds
    (5 / 20)^2 = 6 %). The window widens to hold the disc: the default gives the wide window's answer."""
    f, n_f, d, pitch = 4e-3, 2.0, 5.0, 0.5e-6
    optics = WavefrontOptics(f_number=n_f, focal_length_m=f, pupil_samples=128)
    n = 201
    yy, xx = torch.meshgrid(torch.arange(n) - n // 2, torch.arange(n) - n // 2, indexing="ij")
    r = torch.sqrt((xx**2 + yy**2).double()) * pitch
    default = optics.defocus_maps(_point(n), pitch, d)[0]
    wide = optics.defocus_maps(_point(n), pitch, d, psf_size=n)[0]
    assert float(default[r <= 5e-6].sum()) == pytest.approx((5 / 20) ** 2, abs=0.02)
    assert float(default[r <= 5e-6].sum()) == pytest.approx(float(wide[r <= 5e-6].sum()), abs=0.01)


def test_the_window_holds_every_zernike_terms_blur_and_a_batch_is_refused():
    """The window was sized for defocus alone: 0.3 um of primary spherical at f/2, 4 mm (geometric blur radius
    2 N max|grad W| = 31 um) wrapped round the default 33 samples of 0.5 um, 0.34 of the light within 5 um where a
    wide window gives 0.245. A batched optics gave item 0's blur for all, with no word."""
    z = torch.zeros(13, dtype=torch.float64)
    z[12] = 0.3
    optics = WavefrontOptics(z, f_number=2.0, focal_length_m=4e-3)
    n, pitch = 201, 0.5e-6
    yy, xx = torch.meshgrid(torch.arange(n) - n // 2, torch.arange(n) - n // 2, indexing="ij")
    r = torch.sqrt((xx**2 + yy**2).double()) * pitch
    default = optics.defocus_maps(_point(n), pitch, 0.0)[0]
    wide = optics.defocus_maps(_point(n), pitch, 0.0, psf_size=n)[0]
    for radius in (5e-6, 8e-6):
        assert float(default[r <= radius].sum()) == pytest.approx(float(wide[r <= radius].sum()), abs=0.005)
    for kw, name in (({"zernike_um": torch.zeros(2, 5, dtype=torch.float64)}, "zernike_um"),
                     ({"defocus_diopters": [0.0, 2.0]}, "defocus_diopters"),
                     ({"focal_length_m": [4e-3, 8e-3]}, "focal_length_m")):
        with pytest.raises(ValueError, match=f"^{name}: defocus_maps needs one optics, got 2 batch items"):
            WavefrontOptics(**{"f_number": 2.0, **kw}).defocus_maps(_point(9), pitch, 0.0)
