"""Camera: end-to-end colour accuracy, white balance through the whole chain, intermediates, resuming,
configs."""

import math
from pathlib import Path

import pytest
import torch

from isettorch.camera import Camera
from isettorch.isp.chart import macbeth_delta_e, patch_means
from isettorch.isp.colour import srgb_decode
from isettorch.isp.pipeline import ImageProcessor
from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import macbeth, uniform
from isettorch.sensor import Sensor

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "cameras"


def _camera(filters="nikon_5100", cfa="RGGB", **isp):
    # 9 um pixels: the sensor (50 x 74) just fits the 10 deg chart's optical image (f = 3.86 mm).
    sensor = Sensor(cfa=cfa, filters=filters, auto_exposure="luminance", pixel_size_m=9e-6)
    isp.setdefault("scaling", "exposure")
    isp.setdefault("clip_negative_xyz", False)
    return Camera(DiffractionLimitedOptics(f_number=4.0), sensor, ImageProcessor(**isp), noise=False)


def test_nikon_camera_mcc_optimised_macbeth_delta_e_below_2():
    cam = _camera().double()
    out = cam(macbeth(patch_size=8, dtype=torch.float64), return_intermediates=True)
    acc = macbeth_delta_e(patch_means(out.isp.xyz), "D65")
    assert acc.mean.item() < 2.0, acc.delta_e
    # The encoded sRGB output, decoded and compared with the chart's true colours, is as accurate.
    srgb_to_xyz = torch.linalg.inv(cam.isp.xyz_to_display.matrix.double())
    xyz = torch.einsum("kc,bchw->bkhw", srgb_to_xyz, srgb_decode(out.image))
    assert macbeth_delta_e(patch_means(xyz), "D65").mean.item() < 2.0
    # Without a colour matrix (identity) the same camera is far off: the test can fail.
    cam.isp.sensor_to_xyz.set_matrix(torch.eye(3, dtype=torch.float64))
    out = cam(macbeth(patch_size=8, dtype=torch.float64), return_intermediates=True)
    assert macbeth_delta_e(patch_means(out.isp.xyz), "D65").mean.item() > 5.0


@pytest.mark.parametrize("space", ["xyz", "sensor"])
def test_gray_world_neutral_scene_under_illuminant_a(space):
    cam = _camera(filters="isetcam_rgb", cfa="GBRG", illuminant_correction="gray_world",
                  correction_space=space).double()
    scene = uniform("A", size=16, dtype=torch.float64)
    out = cam(scene, return_intermediates=True)
    rgb = out.isp.display_linear[..., 4:-4, 4:-4].mean((-2, -1))[0]
    assert (rgb / rgb.mean() - 1).abs().max().item() < 0.01, rgb


def test_intermediates_resume_and_batch():
    cam = _camera(filters="isetcam_rgb")
    scene = macbeth(patch_size=4)
    out = cam(scene, return_intermediates=True)
    assert out.optical_image is not None and out.raw.data.shape == (1, 1, 50, 74)
    assert out.image.shape == (1, 3, 50, 74) and out.demosaiced.shape == (1, 3, 50, 74)
    torch.testing.assert_close(cam.from_raw(out.raw), out.image)
    torch.testing.assert_close(cam.from_optical_image(out.optical_image), out.image)
    torch.testing.assert_close(cam.from_demosaiced(out.demosaiced), out.image)
    # A user edit of the optical image (half the light, fixed exposure) halves the linear output.
    t = out.raw.exposure_s
    half = out.optical_image.replace(photons=out.optical_image.photons * 0.5)
    res = cam.from_optical_image(half, True, exposure_s=t)
    torch.testing.assert_close(res.isp.display_linear, 0.5 * out.isp.display_linear, rtol=1e-4, atol=1e-6)
    # Batched scenes give the per-scene results.
    two = type(scene).cat([scene, scene.set_mean_luminance(50.0)])
    both = cam(two, exposure_s=t)
    torch.testing.assert_close(both[:1], cam(scene, exposure_s=t))


def test_camera_to_float64():
    cam = _camera(filters="isetcam_rgb").to(torch.float64)
    img = cam(macbeth(patch_size=4, dtype=torch.float64))
    assert img.dtype == torch.float64 and torch.isfinite(img).all()


@pytest.mark.parametrize("name", ["default", "paper2004_cds", "imx363"])
def test_configs_load_and_run(name):
    cam = Camera.from_config(CONFIGS / f"{name}.yaml")
    cam.sensor.rows, cam.sensor.cols = 24, 32
    img = cam(macbeth(patch_size=4))
    assert img.shape == (1, 3, 24, 32) and torch.isfinite(img).all() and img.max() > 0.1


def test_config_errors_name_the_key(tmp_path):
    import yaml

    cfg = yaml.safe_load((CONFIGS / "default.yaml").read_text())
    bad = dict(cfg, sensor=dict(cfg["sensor"], pixel_size=3e-6))
    with pytest.raises(ValueError, match=r"'pixel_size'.*sensor.*did you mean 'pixel_size_m'"):
        Camera.from_config(bad)
    bad = dict(cfg, isp=dict(cfg["isp"], illuminant_corection="gray_world"))
    with pytest.raises(ValueError, match=r"'illuminant_corection'.*'illuminant_correction'"):
        Camera.from_config(bad)
    bad = dict(cfg, optik={})
    with pytest.raises(ValueError, match=r"'optik'.*'optics'"):
        Camera.from_config(bad)
    bad = dict(cfg, isp=dict(cfg["isp"], scaling=3))
    with pytest.raises(TypeError, match="isp.scaling"):
        Camera.from_config(bad)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(dict(cfg, optics=dict(cfg["optics"], fnumber=2.0))))
    with pytest.raises(ValueError, match=r"'fnumber'.*'f_number'"):
        Camera.from_config(path)
    path.write_text("name: x\nsensor: [\n")  # a flow sequence never closed: malformed YAML at the end, line 3
    with pytest.raises(ValueError, match=r"bad\.yaml' is not valid YAML at line 3, column 1 \(expected the node"):
        Camera.from_config(path)
    # values: a boolean key takes a YAML boolean ('no' is a string, not False), a number key a finite number
    bad = dict(cfg, sensor=dict(cfg["sensor"], cds="no"))
    with pytest.raises(TypeError, match=r"config: sensor\.cds must be true or false \(a YAML boolean\), got str"):
        Camera.from_config(bad)
    bad = dict(cfg, sensor=dict(cfg["sensor"], fill_factor="0.9"))
    with pytest.raises(TypeError, match=r"config: sensor\.fill_factor must be a number"):
        Camera.from_config(bad)
    # the modules' range errors name their arguments; from a config they name the key (they said 'method: ...' for
    # sensor.pixel_optics.method, 'f_number: ...' for optics.f_number, 'method: ...' for isp.illuminant_correction)
    for section, key, value, match in [
            ("sensor", "pixel_optics", {"method": "bogus"}, r"^config: sensor\.pixel_optics\.method: expected one"),
            ("sensor", "pixel_optics", {"method": "optimal", "model": "x"}, r"^config: sensor\.pixel_optics\.model:"),
            ("sensor", "adc_bits", 40, r"^config: sensor\.adc_bits: expected None \(analog\) or an integer"),
            ("sensor", "read_noise_v", -1.0, r"^config: sensor\.read_noise_v: expected a non-negative number"),
            ("optics", "f_number", 0.1, r"^config: optics\.f_number: expected a finite scalar"),
            ("optics", "pad_mode", "x", r"^config: optics\.pad_mode: expected one of"),
            ("isp", "illuminant_correction", "x", r"^config: isp\.illuminant_correction: unknown illuminant"),
            ("isp", "correction_space", "lab", r"^config: isp\.correction_space: expected 'xyz' or 'sensor'")]:
        bad = dict(cfg, **{section: dict(cfg[section], **{key: value})})
        with pytest.raises(ValueError, match=match):
            Camera.from_config(bad)
    # YAML 1.2 floats: 1e-2 is a number (PyYAML's YAML 1.1 resolver alone reads it as the string '1e-2')
    text = (CONFIGS / "default.yaml").read_text()
    path.write_text(text.replace("auto_exposure: luminance", "auto_exposure: null\n  exposure_s: 1e-2"))
    assert Camera.from_config(path).sensor.exposure_s == 0.01


def test_warns_when_the_scene_is_coarser_than_the_pixels():
    # Friction 1 of issue 18: a scene sampled more coarsely than the pixels rendered without a word.
    import warnings

    from isettorch.scene import slanted_edge

    cam = Camera.from_config("default")
    f, pitch = float(cam.optics.focal_length_m), cam.sensor.pixel_size_m
    hfov = math.degrees(2 * math.atan(128 * pitch / (2 * f)))  # the sensor is 128 pixels wide
    with pytest.warns(UserWarning, match=r"coarser than the pixel grid.*pixel pitch 2\.8 um \(2\.0\d+ pixels per "
                                         r"sample\).*at least 2\.0\d+x more finely"):
        cam(slanted_edge(64, hfov_deg=hfov))  # 64 samples for 128 pixels
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cam(slanted_edge(256, hfov_deg=hfov))  # 2 samples per pixel: no warning


def test_flags_and_the_window_margin_are_checked_not_coerced():
    """Bad-input audit: Camera(noise='no') and crop_to_sensor='no' were True, sensor_window_margin=2.7 was 2 (and
    -5 failed later with a crop error), Camera(None, 'sensor') failed at the first render; Sensor(cds='no') had CDS,
    learnable_filters='no' made the filters trainable, capture(noise='yes') was read as a flag. One check_bool."""
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.sensor import Sensor

    optics, sensor = DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3), Sensor(rows=8, cols=8)
    for kw, error, message in (({"noise": "no"}, TypeError, "noise: expected True or False, got 'no'"),
                               ({"crop_to_sensor": "no"}, TypeError, "crop_to_sensor: expected True or False"),
                               ({"sensor_window_margin": 2.7}, ValueError, "sensor_window_margin: expected an integer"),
                               ({"sensor_window_margin": -5}, ValueError, "sensor_window_margin: expected an integer")):
        with pytest.raises(error, match=message):
            Camera(optics, sensor, **kw)
    with pytest.raises(TypeError, match="optics: expected an nn.Module"):
        Camera(None, sensor)
    for kw in ({"cds": "no"}, {"learnable_filters": "no"}):
        with pytest.raises(TypeError, match=f"{next(iter(kw))}: expected True or False"):
            Sensor(**kw)
    with pytest.raises(TypeError, match="noise: expected True or False, got 'yes'"):
        sensor.capture(torch.ones(1, 1, 8, 8), exposure_s=0.01, noise="yes")


def test_resuming_checks_return_intermediates_as_forward_does():
    """from_optical_image(oi, 'no') and from_raw(raw, 'no') returned the intermediates and from_raw(raw, 0) the image,
    where forward refuses anything but True or False."""
    cam = Camera(DiffractionLimitedOptics(), Sensor(rows=8, cols=8, cfa="RGGB", pixel_size_m=2.8e-6, exposure_s=1e-3),
                 noise=False)
    out = cam(uniform("D65", size=32, dtype=torch.float64), return_intermediates=True)
    for call in (lambda: cam.from_optical_image(out.optical_image, "no"), lambda: cam.from_raw(out.raw, "no"),
                 lambda: cam.from_raw(out.raw, 0), lambda: cam.from_demosaiced(out.demosaiced, "yes")):
        with pytest.raises(TypeError, match="return_intermediates: expected True or False"):
            call()
