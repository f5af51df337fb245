"""Camera computes only the optical-image window its sensor sees, with the same result."""

import pytest

from isettorch import scene as scenes
from isettorch.camera import Camera
from isettorch.optics import DiffractionLimitedOptics
from isettorch.sensor import Sensor


@pytest.mark.parametrize("pad_mode,tol", [("zero", 2e-3), ("isetcam", 1e-6)])
@pytest.mark.parametrize("sampling", ["area", "isetcam"])
def test_window_matches_full_optical_image(pad_mode, tol, sampling):
    sc = scenes.dead_leaves(size=96, seed=1)
    optics = DiffractionLimitedOptics(f_number=4.0, pad_mode=pad_mode)
    sensor = Sensor(rows=12, cols=16, pixel_size_m=2.8e-6, exposure_s=0.01, sampling=sampling)
    full = Camera(optics, sensor, crop_to_sensor=False, noise=False)
    crop = Camera(optics, sensor, crop_to_sensor=True, noise=False)
    top, left, h, w = crop.sensor_window(sc)
    full_h, full_w = optics.plan(sc)["full_shape"]
    # centred: equal margins on both sides, so the cropped grid keeps the optical axis at its centre
    assert top == full_h - top - h and left == full_w - left - w
    a = full(sc, return_intermediates=True)
    b = crop(sc, return_intermediates=True)
    assert b.optical_image.photons.shape[-2:] == (h, w)
    ra, rb = a.raw.noise_free, b.raw.noise_free
    assert float((ra - rb).abs().max() / ra.abs().max()) < tol


def test_no_window_when_sensor_fills_the_image():
    sc = scenes.uniform(size=16)
    optics = DiffractionLimitedOptics(f_number=4.0)
    cam = Camera(optics, Sensor(rows=None, cols=None, pixel_size_m=2.8e-6, exposure_s=0.01))
    assert cam.sensor_window(sc) is None
    big = Camera(optics, Sensor(rows=4000, cols=4000, pixel_size_m=2.8e-6, exposure_s=0.01))
    assert big.sensor_window(sc) is None
