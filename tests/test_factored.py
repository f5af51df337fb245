"""Factored spectral images (maps x spectra) against their dense form, through scene, optics, sensor and camera.

The factored path computes the same physics in another order (linearity of the camera equation, the OTF blur and
the spectral integrals), so every result must equal the dense one to float rounding.
"""

from __future__ import annotations

import pytest
import torch

from isettorch import scene as sc
from isettorch.image import SpectralFactors
from isettorch.optics import DiffractionLimitedOptics, ShiftInvariantOptics, WavefrontOptics
from isettorch.scene import Scene
from isettorch.sensor import Sensor

W = torch.arange(400.0, 701.0, 10.0)

SCENES = {
    "uniform": lambda dt, dev: sc.uniform("D65", size=24, dtype=dt, device=dev),
    "sweep": lambda dt, dev: sc.frequency_sweep(size=32, dtype=dt, device=dev),
    "slanted_edge": lambda dt, dev: sc.slanted_edge(size=32, dtype=dt, device=dev),
    "checkerboard": lambda dt, dev: sc.checkerboard(size=32, square_size=4, dtype=dt, device=dev),
    "macbeth": lambda dt, dev: sc.macbeth(patch_size=6, dtype=dt, device=dev),
    "dead_leaves_gray": lambda dt, dev: sc.dead_leaves(32, generator=torch.Generator().manual_seed(1), dtype=dt,
                                                       device=dev),
    "dead_leaves_macbeth": lambda dt, dev: sc.dead_leaves(32, reflectances="macbeth",
                                                          generator=torch.Generator().manual_seed(2), dtype=dt,
                                                          device=dev),
    "rgb_on_display": lambda dt, dev: sc.from_rgb(torch.rand(1, 3, 20, 28, generator=torch.Generator().manual_seed(3),
                                                             dtype=dt).to(dev), wavelengths=W.to(dt)),
}


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max())


def _rtol(dtype) -> float:
    return 1e-5 if dtype == torch.float32 else 1e-12


@pytest.mark.parametrize("kind", sorted(SCENES))
def test_builtin_scene_is_factored_and_equals_its_dense_form(kind, device, dtype):
    s = SCENES[kind](dtype, device)
    assert s.is_factored and s.dtype == dtype and s.device.type == device.type
    d = s.to_dense()
    assert not d.is_factored and s.is_factored  # to_dense leaves the factored scene as it was
    dense = torch.einsum("bjl,bjhw->blhw", s.spectra, s.maps)
    assert torch.equal(d.photons, s.photons)
    assert _rel(d.photons, dense) < _rtol(dtype)
    # spectral integrals without the cube: projection, XYZ, luminance, mean spectrum, crop, batch selection
    wts = torch.rand(s.num_wavelengths, 4, generator=torch.Generator().manual_seed(0), dtype=dtype).to(device)
    assert _rel(s.project(wts), torch.einsum("blhw,lk->bkhw", dense, wts)) < _rtol(dtype)
    fresh = SCENES[kind](dtype, device)
    assert _rel(fresh.xyz(), d.xyz()) < _rtol(dtype)
    assert _rel(fresh.mean_luminance(), d.mean_luminance()) < _rtol(dtype)
    assert _rel(fresh.mean_spectrum(), d.mean_spectrum()) < _rtol(dtype)
    c = fresh.crop(2, 3, 10, 12)
    assert c.is_factored and torch.equal(c.photons, d.crop(2, 3, 10, 12).photons.to(c.dtype)) or \
        _rel(c.photons, d.crop(2, 3, 10, 12).photons) < _rtol(dtype)
    assert fresh.__dict__.get("_photons") is None  # nothing above built the cube of `fresh`


def test_scene_mean_luminance_scaling_and_cat_keep_the_factored_form():
    a = sc.uniform("D65", size=8, dtype=torch.float64)
    b = sc.slanted_edge(size=8, dtype=torch.float64)
    a2 = a.set_mean_luminance(37.0)
    assert a2.is_factored
    assert float(a2.mean_luminance()) == pytest.approx(37.0, rel=1e-12)
    both = Scene.cat([a2, b])
    assert both.is_factored and both.batch_size == 2
    assert torch.allclose(both.photons, torch.cat([a2.photons, b.photons]), rtol=1e-14, atol=0)
    assert torch.allclose(both[1].photons, b.photons, rtol=1e-14, atol=0)
    r = b.resample_wavelengths(torch.arange(405.0, 696.0, 5.0))
    assert r.is_factored
    assert torch.allclose(r.photons, b.to_dense().resample_wavelengths(torch.arange(405.0, 696.0, 5.0)).photons,
                          rtol=1e-13, atol=0)


def test_factors_check_their_inputs():
    with pytest.raises(ValueError, match="maps"):
        SpectralFactors(-torch.ones(1, 1, 2, 2), torch.ones(1, 1, 3))
    with pytest.raises(ValueError, match="spectra"):
        SpectralFactors(torch.ones(1, 2, 2, 2), torch.ones(1, 3, 3))
    with pytest.raises(ValueError, match="photons"):
        Scene(torch.ones(1, 3, 2, 2), W[:3], factors=SpectralFactors(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 3)))
    with pytest.raises(ValueError, match="wavelengths_nm"):
        Scene.from_factors(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 3), W[:4])


def _optics(name, dtype):
    if name == "diffraction":
        return DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3, transmittance=torch.linspace(0.8, 1.0, 31),
                                        transmittance_wavelengths_nm=W)
    if name == "diffraction_mean_pad":
        return DiffractionLimitedOptics(f_number=8.0, focal_length_m=4e-3, pad_mode="mean",
                                        relative_illumination="isetcam")
    if name == "shift_invariant":
        y = torch.arange(-8, 9, dtype=torch.float64) * 0.5e-6
        psf = torch.exp(-(y[:, None] ** 2 + (1.3 * y[None, :]) ** 2) / (2 * (1.2e-6) ** 2))  # anisotropic
        return ShiftInvariantOptics(psf / psf.sum(), 0.5e-6, f_number=4.0, focal_length_m=4e-3)
    return WavefrontOptics(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.05, 0.0, 0.08]), f_number=4.0, focal_length_m=4e-3,
                           pupil_samples=32)


@pytest.mark.parametrize("optics_name", ["diffraction", "diffraction_mean_pad", "shift_invariant", "wavefront"])
@pytest.mark.parametrize("kind", sorted(SCENES))
def test_factored_optics_and_sensor_equal_the_dense_path(kind, optics_name):
    """Optical image, electron rates, noise-free and noisy raw: factored == dense to float64 rounding."""
    dtype = torch.float64
    s = SCENES[kind](dtype, torch.device("cpu"))
    # ~0.6 um samples: the blur spans a few samples and every OTF is ~0 at the grid's Nyquist frequency (a coarser
    # grid cuts the OTF there: ringing, negative irradiance in both paths)
    s = s.replace(hfov_deg=torch.full((1,), 0.3, dtype=dtype))
    optics = _optics(optics_name, dtype)
    d = s.to_dense()
    for crop in (None, (3, 4, 14, 16)):
        oi_f = optics(s, crop=crop)
        oi_d = optics(d, crop=crop)
        assert oi_f.is_factored and not oi_d.is_factored
        assert oi_f.photons.shape == oi_d.photons.shape
        assert _rel(oi_f.photons, oi_d.photons) < 1e-10
        assert _rel(oi_f.xyz(), oi_d.xyz()) < 1e-10
        for k in ("sample_spacing_m", "image_distance_m", "f_number"):
            assert torch.equal(getattr(oi_f, k), getattr(oi_d, k))
        assert oi_f.metadata == oi_d.metadata and (oi_f.pad_rows, oi_f.pad_cols) == (oi_d.pad_rows, oi_d.pad_cols)
    sensor = Sensor(rows=8, cols=10, pixel_size_m=2.2e-6, cfa="RGGB", adc_bits=12, shot_noise="gaussian",
                    read_noise_v=1e-3, auto_exposure="luminance")
    oi_f, oi_d = optics(s), optics(d)
    raw_f = sensor(oi_f, generator=torch.Generator().manual_seed(5))
    raw_d = sensor(oi_d, generator=torch.Generator().manual_seed(5))
    assert oi_f.__dict__.get("_photons") is None  # the sensor projected the factored image, no cube
    assert _rel(raw_f.exposure_s, raw_d.exposure_s) < 1e-10
    assert _rel(raw_f.electrons, raw_d.electrons) < 1e-10
    assert _rel(raw_f.noise_free, raw_d.noise_free) < 1e-10
    # the noisy DN: same draws; a rounding-level change of the signal may move a value across an ADC step
    assert (raw_f.data - raw_d.data).abs().max() <= 1
    assert float((raw_f.data != raw_d.data).double().mean()) < 0.05


def test_gradients_flow_through_the_factored_path():
    """gradcheck (float64) of electron rates w.r.t. the maps and spectra, through the diffraction optics."""
    dtype = torch.float64
    g = torch.Generator().manual_seed(0)
    maps = torch.rand(1, 2, 6, 6, generator=g, dtype=dtype).requires_grad_()
    spectra = (torch.rand(1, 2, 5, generator=g, dtype=dtype) * 1e15).requires_grad_()
    w = torch.arange(450.0, 651.0, 50.0, dtype=dtype)
    optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3)
    sensor = Sensor(rows=4, cols=4, pixel_size_m=1.5e-6, cfa="RGGB")

    def rate(m, sp):
        scene = Scene.from_factors(m, sp, w, hfov_deg=0.4, validate=False)
        oi = optics(scene)
        assert oi.is_factored
        return sensor.electron_rate(oi)

    assert torch.autograd.gradcheck(lambda m: rate(m, spectra.detach()), (maps,), eps=1e-6, atol=1e-6 * 1e3)
    assert torch.autograd.gradcheck(lambda sp: rate(maps.detach(), sp), (spectra,), eps=1e3, rtol=1e-5, atol=1e-3)


def test_camera_runs_on_the_inputs_device_and_dtype(device, dtype):
    """Scene -> optics -> sensor on the scene's device and dtype, factored all the way (no cube is built)."""
    from isettorch.camera import Camera

    s = sc.macbeth(patch_size=4, dtype=dtype, device=device)
    camera = Camera(DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3).to(device),
                    Sensor(rows=8, cols=12, pixel_size_m=2e-6, cfa="RGGB", adc_bits=10,
                           auto_exposure="luminance").to(device))
    out = camera(s, return_intermediates=True, generator=torch.Generator(device=device).manual_seed(0))
    assert out.optical_image.is_factored and out.optical_image.__dict__.get("_photons") is None
    for t in (out.raw.data, out.raw.noise_free, out.image):
        assert t.dtype == dtype and t.device.type == device.type and bool(torch.isfinite(t).all())


def test_a_factored_scene_read_densely_still_moves_and_detaches():
    """Reading ``.photons`` caches the cube; ``to``/``detach`` must then move the factors, not carry both forms
    (regression: the merged bench hit 'photons: expected None when factors are given')."""
    from isettorch.scene import frequency_sweep

    sc = frequency_sweep(size=32).to(dtype=torch.float64)
    dense = sc.photons.clone()
    moved = sc.to(dtype=torch.float32)
    assert moved.is_factored and moved.photons.dtype == torch.float32
    torch.testing.assert_close(moved.photons.double(), dense, rtol=1e-6, atol=0)
    assert sc.detach().is_factored and torch.equal(sc.detach().photons, dense)


def test_a_factored_scene_keeps_its_grid_length_and_regions_are_slices():
    w31 = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    maps = torch.rand(1, 1, 4, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    s = Scene.from_factors(maps[0], torch.ones(1, 31, dtype=torch.float64), w31, hfov_deg=10.0)
    with pytest.raises(ValueError, match="expected 31 wavelengths"):  # (16 bands on 31-band spectra were kept)
        s.replace(wavelengths_nm=torch.arange(400.0, 701.0, 20.0, dtype=torch.float64))
    # a region is slices: row 0 is not the whole image (an int 0 was read as 'all rows', 3 dropped a dimension)
    torch.testing.assert_close(s.mean_spectrum(slice(0, 1)), maps[0, :, 0].mean().expand(1, 31))
    with pytest.raises(TypeError, match="rows: expected a slice"):
        s.mean_spectrum(0)


def test_reading_photons_does_not_change_a_later_render_of_the_same_seed():
    """Reading a factored image's ``.photons`` kept the dense cube, and later calls took the dense path, whose float32
    rounding differs from the factors' (4e-8): the same seed then drew different Poisson noise (a viewer reading its
    optical image's cube came out 0.02 V off a direct render). The factors are the image until the cube is changed;
    a cube changed in place is the image, as before."""
    s = sc.macbeth(patch_size=4)
    optics = DiffractionLimitedOptics(f_number=2.8, focal_length_m=4e-3)
    sensor = Sensor(rows=16, cols=24, pixel_size_m=2e-6, cfa="RGGB", adc_bits=10, exposure_s=0.01)
    for image, render in ((s, lambda x: sensor(optics(x), generator=torch.Generator().manual_seed(3))),
                          (optics(s), lambda x: sensor(x, generator=torch.Generator().manual_seed(3)))):
        before = render(image)
        _ = image.photons
        assert image.factors_hold_image
        after = render(image)
        assert torch.equal(before.data, after.data) and torch.equal(before.electrons, after.electrons)
        image.photons.mul_(0.5)  # changed in place: the dense cube is the image now
        assert not image.factors_hold_image
        halved = render(image)
        torch.testing.assert_close(halved.noise_free, before.noise_free * 0.5, rtol=1e-5, atol=1e-7)


def test_reading_photons_under_inference_mode_still_renders():
    """An inference tensor has no version counter: reading a factored image's cube under torch.inference_mode must
    not fail (it raised 'Inference tensors do not track version counter'); the dense path then, as before."""
    with torch.inference_mode():
        oi = DiffractionLimitedOptics(f_number=2.8, focal_length_m=4e-3)(sc.macbeth(patch_size=4))
        dense = oi.photons
        assert not oi.factors_hold_image
        raw = Sensor(rows=8, cols=8, exposure_s=0.01)(oi, generator=torch.Generator().manual_seed(1))
        ref = Sensor(rows=8, cols=8, exposure_s=0.01)(oi.replace(photons=dense, factors=None),
                                                      generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(raw.electrons, ref.electrons, rtol=0, atol=0)


def test_an_image_whose_cube_changed_in_place_keeps_the_change_in_every_operation():
    """A factored image's cube changed in place is the image (factors_hold_image), but to, detach, [i], crop,
    resample_wavelengths, set_mean_luminance and Scene.cat had rebuilt from the unchanged factors: after
    photons.mul_(2), set_mean_luminance(100) gave 50 cd/m^2 and the others half the radiance. Also: a copy has its
    own metadata dict (a key set on a crop had appeared on the original), to() refuses a non-float dtype (int32 had
    truncated a dense image, and was ignored for a factored one), an empty selection of a factored image is
    refused as a dense one's is, and Scene.cat names a non-Scene."""
    s = sc.macbeth(patch_size=4).replace(hfov_deg=torch.tensor([10.0]))
    s = Scene.cat([s, s.set_mean_luminance(50.0)])
    lum = s.mean_luminance().clone()
    s.photons.mul_(2)
    assert not s.factors_hold_image
    torch.testing.assert_close(s.mean_luminance(), 2 * lum)
    for out, want in ((s.to(dtype=torch.float64).mean_luminance(), 2 * lum), (s.detach().mean_luminance(), 2 * lum),
                      (s[1].mean_luminance(), 2 * lum[1:]),
                      (s.resample_wavelengths(torch.arange(400.0, 701.0, 10.0)).mean_luminance(), 2 * lum),
                      (Scene.cat([s, s]).mean_luminance(), 2 * lum.repeat(2)),
                      (s.set_mean_luminance(100.0).mean_luminance(), torch.full_like(lum, 100.0))):
        torch.testing.assert_close(out.to(lum.dtype), want, rtol=1e-5, atol=0)
    crop = s.crop(0, 0, 8, 12)
    torch.testing.assert_close(crop.photons, s.photons[:, :, :8, :12])
    crop.metadata["note"] = 1
    assert "note" not in s.metadata
    with pytest.raises(ValueError, match=r"^dtype: expected a floating torch dtype"):
        s.to(dtype=torch.int32)
    with pytest.raises(ValueError, match=r"^index: slice\(5, 6, None\) selects no items of the batch of 2"):
        Scene.cat([sc.macbeth(patch_size=4)] * 2)[5:6]
    with pytest.raises(TypeError, match=r"^scenes\[1\]: expected a Scene, got int"):
        Scene.cat([s, 3])


def test_an_optical_image_crop_keeps_a_field_of_view_given_without_a_distance():
    """With hfov_deg given and no focal length or image distance, a crop's field of view was None."""
    from isettorch.optics.optical_image import OpticalImage

    oi = OpticalImage(torch.ones(1, 3, 8, 8), torch.tensor([450.0, 550.0, 650.0]), hfov_deg=20.0)
    crop = oi.crop(0, 0, 4, 4)
    expected = 2 * torch.rad2deg(torch.atan(torch.tan(torch.deg2rad(torch.tensor(10.0))) * 4 / 8))
    torch.testing.assert_close(crop.hfov_deg, expected.reshape(1))
