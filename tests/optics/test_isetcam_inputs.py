"""ISETCam-convention optics (isettorch.optics.isetcam): the factored path checks its radiance as the dense one does,
a lens passes at most its light, and gradients to the frequency grid's inputs are finite."""

import math

import pytest
import torch

from isettorch.optics.isetcam import compute_oi, compute_oi_factored, dl_otf_isetcam

WAVE = torch.arange(400.0, 701.0, 10.0)
ARGS = (WAVE, 10.0, 1.2, 4.0, 3.86e-3)


def test_a_factored_radiance_negative_somewhere_is_refused_as_the_dense_one_is():
    """The check looked at the product's maximum only; the negative half then came out as positive irradiance
    (oiCompute's abs)."""
    maps = torch.ones(1, 8, 8, dtype=torch.float64)
    maps[:, :, :4] = -1.0
    spectra = torch.full((1, 31), 1e15, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"maps, spectra: expected a non-negative radiance .*minimum is -"):
        compute_oi_factored(maps, spectra, *ARGS)
    with pytest.raises(ValueError, match=r"scene_photons: expected non-negative values, minimum is -1e\+15"):
        compute_oi(maps * spectra[0][:, None, None], *ARGS)
    # signed factors whose product is non-negative are fine (two signed terms: (1 - x) + x = 1)
    x = torch.linspace(0, 1, 8, dtype=torch.float64).expand(8, 8)
    two = torch.stack([1 - 2 * x, 2 * x])
    spec = torch.stack([torch.full((31,), 2e15), torch.full((31,), 1e15)]).double()
    ok = compute_oi_factored(two, spec, *ARGS).photons
    assert torch.allclose(ok, compute_oi((two[:, None] * spec[:, :, None, None]).sum(0), *ARGS).photons, rtol=1e-12)


@pytest.mark.parametrize("which", ["maps", "spectra"])
def test_a_factored_radiance_with_nan_is_named(which):
    maps, spectra = torch.ones(1, 8, 8), torch.full((1, 31), 1e15)
    (maps if which == "maps" else spectra)[0, 0] = math.nan
    with pytest.raises(ValueError, match=rf"{which}: expected finite values"):
        compute_oi_factored(maps, spectra, *ARGS)


def test_a_lens_transmittance_above_one_is_refused():
    with pytest.raises(ValueError, match=r"transmittance: expected values in \[0, 1\] .*maximum of 5"):
        compute_oi(torch.ones(31, 8, 8), *ARGS, transmittance=torch.full((31,), 5.0))


def test_gradients_to_the_field_of_view_and_focal_length_are_finite_and_match_finite_differences():
    """sqrt(fx^2 + fy^2) at DC has an infinite derivative: times the 0 of d(r2) it made d/d hfov_deg NaN."""
    photons = torch.rand(1, 3, 6, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 1e3
    wave = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)
    hfov = torch.tensor([10.0], dtype=torch.float64, requires_grad=True)
    f = torch.tensor([3.86e-3], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda h, f_: compute_oi(photons, wave, h, 1.2, 4.0, f_).photons, (hfov, f))
    dx = 2 * 3.86e-3 * math.tan(math.radians(5.0)) / 8
    otf, _, _ = dl_otf_isetcam(wave, torch.tensor([4.0], dtype=torch.float64), torch.tensor([3.86e-3]).double(),
                               hfov, torch.tensor([dx], dtype=torch.float64), 6, 8)
    assert float(otf.detach()[0, :, 0, 0].min()) == 1.0  # the DC value is exact
    (g,) = torch.autograd.grad(otf.sum(), hfov)
    assert math.isfinite(float(g)) and float(g) != 0.0


def test_isetcam_functions_name_bad_dtypes_otf_inputs_and_empty_images():
    # dtype=torch.int32 returned -2147483648 for 4.8e13 photons (int64: 0 for 0.18); dl_otf_isetcam's f/0 gave an
    # OTF of 1 everywhere, f/-4 or a negative wavelength values above 1, a NaN wavelength 0; empty images failed in
    # aminmax / with an IndexError; unit_frequency_list(0) in max().
    from isettorch.optics.isetcam import compute_oi, compute_oi_factored, dl_otf_isetcam, unit_frequency_list

    w = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)
    x = torch.ones(1, 3, 8, 10, dtype=torch.float64)
    for dt in (torch.int32, torch.int64, torch.float16):
        with pytest.raises(ValueError, match=r"dtype: expected torch.float32 or torch.float64"):
            compute_oi(x, w, 10, 1.2, 4, 4e-3, dtype=dt)
        with pytest.raises(ValueError, match=r"dtype: expected torch.float32 or torch.float64"):
            compute_oi_factored(x[:, :1], torch.ones(1, 1, 3), w, 10, 1.2, 4, 4e-3, dtype=dt)
    with pytest.raises(ValueError, match="scene_photons: expected real radiance"):
        compute_oi(torch.ones(1, 3, 0, 5), w, 10, 1.2, 4, 4e-3)
    with pytest.raises(ValueError, match="maps: expected real values, at least one term"):
        compute_oi_factored(torch.ones(1, 0, 8, 10), torch.ones(1, 0, 3), w, 10, 1.2, 4, 4e-3)
    one = torch.ones(1, dtype=torch.float64)
    ok = dict(wavelengths_nm=w, f_number=4 * one, focal_length_m=4e-3 * one, hfov_deg=10 * one, dx_m=1e-6 * one,
              height=8, width=10)
    assert dl_otf_isetcam(**ok)[0].max() <= 1
    for key, bad in (("f_number", 0 * one), ("f_number", -4 * one), ("wavelengths_nm", -w),
                     ("wavelengths_nm", torch.tensor([float("nan")])), ("hfov_deg", -10 * one)):
        with pytest.raises(ValueError, match=f"{key}: expected finite positive values"):
            dl_otf_isetcam(**{**ok, key: bad})
    with pytest.raises(ValueError, match="height: expected a whole number of samples >= 1"):
        dl_otf_isetcam(**{**ok, "height": 0})
    with pytest.raises(ValueError, match="n: expected a whole number"):
        unit_frequency_list(0)
