"""The Scene container: validation, geometry, photometry."""

import math

import pytest
import torch

from isettorch import Scene, spectral


def _scene(b=2, l=31, h=6, w=8, **kw):
    g = torch.Generator().manual_seed(b * 1000 + l)
    return Scene(torch.rand(b, l, h, w, dtype=torch.float64, generator=g) * 1e16, spectral.default_wavelengths(
        dtype=torch.float64)[:l], **kw)


def test_geometry():
    s = _scene(hfov_deg=10.0, distance_m=2.0)
    width = 2 * 2.0 * math.tan(math.radians(5))
    assert torch.allclose(s.sample_spacing_m, torch.full((2,), width / 8, dtype=torch.float64))
    vfov = 2 * math.degrees(math.atan(6 / 8 * math.tan(math.radians(5))))
    assert s.vfov_deg[0].item() == pytest.approx(vfov, rel=1e-12)
    c = s.crop(1, 2, 4, 4)
    assert torch.allclose(c.sample_spacing_m, s.sample_spacing_m)
    assert c.photons.shape == (2, 31, 4, 4)
    assert torch.equal(c.photons, s.photons[:, :, 1:5, 2:6])


def test_set_mean_luminance_exact():
    s = _scene().set_mean_luminance(100.0)
    assert torch.allclose(s.mean_luminance(), torch.full((2,), 100.0, dtype=torch.float64), rtol=1e-5)
    s32 = _scene().to(dtype=torch.float32).set_mean_luminance(torch.tensor([100.0, 3.0]))
    assert torch.allclose(s32.mean_luminance(), torch.tensor([100.0, 3.0]), rtol=1e-5)


def test_a_luminance_beyond_the_dtypes_range_is_refused():
    """float32 radiance overflows near 3.4e38 photons/s/sr/m^2/nm (about 1e22-1e24 cd/m^2 for these scenes): the
    scaled scene was inf or NaN, unsaid. Refused naming the argument, dense and factored; float64 holds it, with the
    luminance asked."""
    from isettorch import scene

    for make in (lambda dt: scene.macbeth(patch_size=4, dtype=dt), lambda dt: _scene().to(dtype=dt)):
        with pytest.raises(ValueError, match="cd_m2: .* beyond the range of torch.float32"):
            make(torch.float32).set_mean_luminance(1e25)
        big = make(torch.float64).set_mean_luminance(1e25)
        assert torch.allclose(big.mean_luminance(), torch.tensor(1e25, dtype=torch.float64), rtol=1e-9)
        ok = make(torch.float32).set_mean_luminance(1e9)  # (the sun's disc is about 1.6e9 cd/m^2)
        assert torch.isfinite(ok.photons).all()
    with pytest.raises(ValueError, match="mean_luminance_cd_m2: .* beyond the range"):
        scene.uniform(size=4, mean_luminance_cd_m2=1e25)


def test_set_mean_luminance_scales_illuminant():
    w = spectral.default_wavelengths(dtype=torch.float64)
    ill = spectral.energy_to_photons(spectral.illuminant("D65", w), w, dim=0)
    s = Scene(0.5 * ill[None, :, None, None].expand(1, -1, 4, 4), w, illuminant_photons=ill)
    s2 = s.set_mean_luminance(50.0)
    assert torch.allclose(s2.reflectance(), torch.full_like(s2.photons, 0.5), rtol=1e-9)
    assert s2.illuminant_luminance().item() == pytest.approx(100.0, rel=1e-9)


def test_an_illuminant_lights_every_band_the_scene_reflects():
    """An illuminant 0 where the radiance is not gave an infinite reflectance, an all-zero one an sRGB preview of
    NaN; both refused, naming it. Bands dark in both (a monochromatic scene) stay allowed; a mean luminance of 0
    (which zeroed the illuminant too) is refused."""
    w = spectral.default_wavelengths(dtype=torch.float64)
    ill = torch.full((31,), 1e15, dtype=torch.float64)
    ill[5] = 0.0
    with pytest.raises(ValueError, match="illuminant_photons: 0 at 450 nm"):
        Scene(torch.full((1, 31, 2, 2), 1e15, dtype=torch.float64), w, illuminant_photons=ill)
    with pytest.raises(ValueError, match="illuminant_photons: expected some light"):
        Scene(torch.full((1, 31, 2, 2), 1e15, dtype=torch.float64), w, illuminant_photons=torch.zeros(31))
    photons = torch.full((1, 31, 2, 2), 1e15, dtype=torch.float64)
    photons[:, 5] = 0.0
    s = Scene(photons, w, illuminant_photons=ill)
    assert torch.isfinite(s.reflectance()).all() and float(s.reflectance()[0, 6, 0, 0]) == 1.0
    # a factored scene: its spectra say which bands hold radiance
    f = Scene.from_factors(torch.ones(1, 1, 2, 2, dtype=torch.float64), torch.full((1, 1, 31), 1e15,
                                                                                  dtype=torch.float64), w)
    with pytest.raises(ValueError, match="illuminant_photons: 0 at 450 nm"):
        f.replace(illuminant_photons=ill)
    with pytest.raises(ValueError, match="cd_m2: expected a positive"):
        _scene().set_mean_luminance(0.0)


def test_xyz_y_is_luminance_and_srgb_range():
    s = _scene()
    assert torch.allclose(s.xyz()[:, 1:2], s.luminance(), rtol=1e-9)
    rgb = s.srgb()
    assert rgb.shape == (2, 3, 6, 8) and rgb.min() >= 0 and rgb.max() <= 1


def test_resample_wavelengths_and_to_and_index():
    s = _scene()
    r = s.resample_wavelengths(spectral.default_wavelengths(400, 700, 5, dtype=torch.float64))
    assert r.num_wavelengths == 61
    assert torch.allclose(r.photons[:, ::2], s.photons)
    assert s.to(dtype=torch.float32).photons.dtype == torch.float32
    assert s[1].batch_size == 1 and torch.equal(s[1].photons[0], s.photons[1])
    both = Scene.cat([s[0], s[1]])
    assert torch.equal(both.photons, s.photons)


@pytest.mark.parametrize("photons,wave,match", [
    (torch.full((1, 3, 2, 2), float("nan")), torch.tensor([400.0, 500.0, 600.0]), "finite"),
    (-torch.ones(1, 3, 2, 2), torch.tensor([400.0, 500.0, 600.0]), "non-negative"),
    (torch.ones(3, 2), torch.tensor([400.0, 500.0, 600.0]), r"\[B, L, H, W\]"),
    (torch.ones(1, 3, 2, 2), torch.tensor([400.0, 500.0]), "expected 3 wavelengths"),
    (torch.ones(1, 3, 2, 2), torch.tensor([400.0, 600.0, 500.0]), "strictly increasing"),
])
def test_bad_input(photons, wave, match):
    with pytest.raises(ValueError, match=match):
        Scene(photons, wave)


def test_bad_fov_and_distance():
    with pytest.raises(ValueError, match="hfov_deg"):
        _scene(hfov_deg=-1.0)
    with pytest.raises(ValueError, match="distance_m"):
        _scene(distance_m=0.0)
    with pytest.raises(ValueError, match="hfov_deg"):
        _scene(hfov_deg=[1.0, 2.0, 3.0])


def test_plots_save_png(tmp_path):
    from isettorch import scene as scenes

    s = scenes.macbeth(patch_size=4)
    fig = s.plot_srgb()
    fig.savefig(tmp_path / "srgb.png")
    # mean radiance of the top-left (dark skin) patch; the plotted line is exactly that region's mean spectrum
    fig2 = s.plot_spectrum(rows=slice(0, 4), cols=slice(0, 4))
    fig2.savefig(tmp_path / "spd.png")
    line = fig2.axes[0].lines[0]
    assert torch.allclose(torch.as_tensor(line.get_ydata(), dtype=s.dtype), s.photons[0, :, :4, :4].mean(dim=(-2, -1)))
    assert (tmp_path / "srgb.png").stat().st_size > 0 and (tmp_path / "spd.png").stat().st_size > 0


def test_replace_validates_like_a_new_scene():
    # Friction 7 of issue 18: Scene.replace used to skip the NaN / negative check of the constructor.
    s = Scene(torch.ones(1, 3, 4, 4), torch.tensor([450.0, 550.0, 650.0]), hfov_deg=10.0)
    bad = s.photons.clone()
    bad[0, 1, 2, 3] = math.nan
    with pytest.raises(ValueError, match="photons"):
        s.replace(photons=bad)
    with pytest.raises(ValueError, match="photons.*non-negative"):
        s.replace(photons=-s.photons)
    with pytest.raises(ValueError, match="illuminant_photons"):
        s.replace(illuminant_photons=torch.tensor([1.0, math.inf, 1.0]))
    ok = s.replace(photons=2 * s.photons)
    assert torch.equal(ok.photons, 2 * s.photons) and torch.equal(ok.hfov_deg, s.hfov_deg)
    # trusted internal changes keep working without the check
    assert s.replace(photons=bad, validate=False).photons.isnan().any()


def test_an_empty_image_is_refused_by_name():
    w = torch.arange(400.0, 701.0, 10.0)
    with pytest.raises(ValueError, match="photons: expected a non-empty"):
        Scene(torch.ones(1, 31, 0, 8), w)


def test_batch_luminances_geometry_and_illuminants_are_checked():
    """A [n] luminance for a batch of B != n, a missing hfov or distance, and a batch mixing scenes with and without
    an illuminant are errors naming the argument (a scene audit found a batch of 1 silently grown to 2, TypeErrors
    later, and the illuminants silently dropped)."""
    from isettorch.scene import uniform

    with pytest.raises(ValueError, match=r"cd_m2: expected a scalar or one luminance per scene \(1\), got 2"):
        _scene(b=1).set_mean_luminance(torch.tensor([50.0, 100.0]))
    with pytest.raises(ValueError, match=r"cd_m2: expected a scalar or one luminance per scene \(3\)"):
        _scene(b=3).set_mean_luminance(torch.tensor([50.0, 100.0]))
    two = _scene(b=2).set_mean_luminance(torch.tensor([50.0, 100.0]))
    torch.testing.assert_close(two.mean_luminance(), torch.tensor([50.0, 100.0], dtype=torch.float64))
    for key in ("hfov_deg", "distance_m"):
        with pytest.raises(ValueError, match=f"{key}: expected a positive number"):
            _scene(**{key: None})
    a = uniform(size=4)
    b = Scene(a.photons.clone(), a.wavelengths_nm)
    with pytest.raises(ValueError, match=r"scenes\[1\]: expected every scene with an illuminant or none"):
        Scene.cat([a, b])
    assert Scene.cat([b, b]).illuminant_photons is None


def test_a_scene_of_invisible_light_is_not_called_black():
    # Only infrared light: its luminance is 0 (V(lambda) = 0 beyond 830 nm), and set_mean_luminance said "the scene is
    # black".
    s = Scene(torch.full((1, 2, 2, 2), 1e16, dtype=torch.float64), torch.tensor([850.0, 940.0], dtype=torch.float64))
    with pytest.raises(ValueError, match=r"no luminance .*light only where V\(lambda\) is 0, here 850-940 nm"):
        s.set_mean_luminance(100.0)
