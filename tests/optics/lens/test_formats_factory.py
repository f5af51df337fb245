"""Optical formats, build_optics for every optics type, and pixel vignetting against closed forms."""

import math

import numpy as np
import pytest
import torch

from isettorch.optics import DiffractionLimitedOptics, ShiftInvariantOptics, WavefrontOptics
from isettorch.optics.factory import build_optics
from isettorch.optics.formats import crop_factor, field_of_view_deg, focal_length_for_fov_mm, optical_format
from isettorch.sensor.pixel_optics import microlens_offset_m, pixel_vignetting


def test_formats():
    ff = optical_format("full frame")
    assert ff.diagonal_mm == pytest.approx(43.2666, abs=1e-4)
    assert crop_factor("APS-C") == pytest.approx(1.534, abs=1e-3)  # the usual "1.5x" of Nikon/Sony APS-C
    # a 50 mm lens on full frame: 46.79 deg diagonal, 39.60 deg horizontal (2 atan(d / 2f))
    assert field_of_view_deg("full frame", 50.0) == pytest.approx(46.793, abs=1e-3)
    assert field_of_view_deg("full frame", 50.0, "horizontal") == pytest.approx(39.598, abs=1e-3)
    assert focal_length_for_fov_mm('1/2.3"', field_of_view_deg('1/2.3"', 4.3)) == pytest.approx(4.3)
    assert optical_format("1/2.3").diagonal_mm == pytest.approx(7.666, abs=1e-3)
    with pytest.raises(ValueError, match="2/3"):
        optical_format('2/3"')


def test_build_optics_every_type(tmp_path):
    assert isinstance(build_optics({"type": "diffraction_limited", "f_number": 2.8}), DiffractionLimitedOptics)
    w = build_optics({"type": "wavefront", "f_number": 4.0, "zernike_um": [0, 0, 0, 0, 0.1]})
    assert isinstance(w, WavefrontOptics)
    psf = np.outer(np.hanning(9), np.hanning(9))
    f = tmp_path / "psf.npz"
    np.savez(f, psf=psf, psf_spacing_m=np.array(1e-6))
    s = build_optics({"type": "psf_file", "path": str(f), "f_number": 4.0})
    assert isinstance(s, ShiftInvariantOptics)
    with pytest.raises(ValueError, match="f_numbr.*f_number"):
        build_optics({"type": "diffraction_limited", "f_numbr": 2.8})
    with pytest.raises(ValueError, match="lenz.*lens"):
        build_optics({"type": "lenz"})
    with pytest.raises(ValueError, match="path"):
        build_optics({"type": "psf_file"})


def test_build_lens_optics():
    pytest.importorskip("opticalglass")
    from isettorch.optics.lens.optics import LensOptics

    o = build_optics({"type": "lens", "lens": "cooke_triplet", "components": 6})
    assert isinstance(o, LensOptics) and o.components == 6
    assert float(o.f_number) == pytest.approx(5.0021, abs=1e-4)


def test_pixel_vignetting_bare_aperture_collimated_is_the_overlap_formula():
    """Collimated light (f/1000) through a bare aperture: the detector catches the displaced aperture's overlap
    (Catrysse & Wandell 2002): (min(p/2 + s, d/2) - max(-p/2 + s, -d/2)) / p * (d / p), s = h tan(theta')."""
    p, d, h, n = 2.0e-6, 1.2e-6, 3.0e-6, 1.46
    cra = torch.tensor([0.0, 5.0, 10.0, 20.0, 30.0])
    got = pixel_vignetting(cra, 1000.0, h, p, d, stack_index=n, microlens=False, samples=21)
    s = h * torch.tan(torch.asin(torch.sin(torch.deg2rad(cra.double())) / n))
    ref = (torch.minimum(p / 2 + s, torch.tensor(d / 2)) - torch.maximum(-p / 2 + s, torch.tensor(-d / 2))
           ).clamp_min(0) / p * (d / p)
    torch.testing.assert_close(got, ref, rtol=1e-2, atol=0)


def test_pixel_vignetting_microlens_is_a_disk_segment():
    """Ideal microlens: a direction is collected when h tan(theta') <= d/2, a window |L| <= L_w in direction
    cosines (for a narrow beam); the collected fraction of the beam's disk (radius a = 1/(2N)) centred at
    L_c is (acos(t) - t sqrt(1 - t^2)) / pi, t = (L_c - L_w) / a (circular segment area)."""
    p, d, h, n, fno = 2.0e-6, 1.0e-6, 3.0e-6, 1.5, 8.0
    lw = n * math.sin(math.atan(d / 2 / h))  # window edge in air direction cosine (on the x axis)
    a = 1 / (2 * fno)
    for t in (-0.8, -0.4, 0.0, 0.4, 0.8):
        lc = lw + t * a
        cra = math.degrees(math.asin(lc))
        ref = (math.acos(t) - t * math.sqrt(1 - t * t)) / math.pi  # part of the disk below the edge at -t a
        got = float(pixel_vignetting(cra, fno, h, p, d, stack_index=n, microlens=True, samples=401))
        assert got == pytest.approx(ref, abs=0.01), t
    # a microlens shifted by microlens_offset_m recentres the beam: full collection again at a large CRA
    cra = math.degrees(math.asin(lw + 0.8 * a))
    off = microlens_offset_m(cra, h, n)
    assert float(pixel_vignetting(cra, fno, h, p, d, stack_index=n, microlens_offset_m=off)) == pytest.approx(1.0)


def test_pixel_vignetting_errors():
    with pytest.raises(ValueError, match="detector_size_m"):
        pixel_vignetting(0.0, 2.0, 3e-6, 1e-6, 2e-6)
    with pytest.raises(ValueError, match="f_number"):
        pixel_vignetting(0.0, -2.0, 3e-6, 2e-6, 1e-6)
    # a NaN angle or offset gave 0, samples of 1-2.5 gave 1.0 (true 0.678), 'no' took the microlens branch
    for kw, error, message in (({"chief_ray_angle_deg": math.nan}, ValueError, "chief_ray_angle_deg"),
                               ({"microlens_offset_m": math.nan}, ValueError, "microlens_offset_m"),
                               ({"samples": 2.5}, ValueError, "samples: expected an integer >= 16"),
                               ({"samples": 2}, ValueError, "samples: expected an integer >= 16"),
                               ({"microlens": "no"}, TypeError, "microlens: expected True or False")):
        args = {"chief_ray_angle_deg": 10.0, **kw}
        with pytest.raises(error, match=message):
            pixel_vignetting(args.pop("chief_ray_angle_deg"), 2.0, 3e-6, 2e-6, 1e-6, **args)
    for args, message in (((math.nan, 3e-6), "chief_ray_angle_deg"), ((10.0, -3e-6), "stack_height_m"),
                          ((90.0, 3e-6), "chief_ray_angle_deg")):
        with pytest.raises(ValueError, match=message):
            microlens_offset_m(*args)


def test_lens_camera_config_renders():
    pytest.importorskip("opticalglass")
    from pathlib import Path

    import yaml

    from isettorch.camera import Camera
    from isettorch.optics.lens.optics import LensOptics
    from isettorch.scene.scene import Scene

    path = Path(__file__).resolve().parents[3] / "configs" / "cameras" / "cooke_lens.yaml"
    cfg = yaml.safe_load(path.read_text())
    assert cfg["optics"]["type"] == "lens"
    cfg["sensor"]["rows"] = cfg["sensor"]["cols"] = 16  # a small window of the optical image for the test
    cam = Camera.from_config(cfg)
    assert isinstance(cam.optics, LensOptics)
    cam.optics = LensOptics(cam.optics.analysis, field_samples=3, azimuth_samples=4, components=4,
                            distortion_samples=5, ri_samples=24)  # a cheaper knob for the test
    wave = torch.arange(450.0, 651.0, 50.0, dtype=torch.float64)
    scene = Scene(torch.full((1, 5, 24, 24), 1e16, dtype=torch.float64), wave, hfov_deg=20.0)
    oi = cam.optics(scene)
    assert torch.isfinite(oi.photons).all() and oi.photons.shape[-1] >= 24
    # the centre of a uniform scene: the camera equation pi / (1 + 4 N^2) (ISETCam, object at infinity; relative
    # illumination 1 on axis), as for LensOptics itself (test_optics.py, to 2e-3 there; 3e-3 here with this test's
    # cheaper PSF and relative-illumination sampling on a 24-sample scene)
    m, n = oi.pad_rows, float(cam.optics.f_number)
    centre = oi.photons[0, :, m + 11:m + 13, m + 11:m + 13]
    torch.testing.assert_close(centre, torch.full_like(centre, 1e16 * math.pi / (1 + 4 * n * n)), rtol=5e-3, atol=0)
    img = cam(scene)
    assert isinstance(img, torch.Tensor) and img.shape == (1, 3, 16, 16) and torch.isfinite(img).all()
