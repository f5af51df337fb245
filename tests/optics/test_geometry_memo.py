"""The per-geometry memo of a shift-invariant optics and a Camera's window (repeated calls do no per-call tensor
work for them) returns what a fresh module computes, and follows changes of the modules' settings."""

import torch
from torch import nn

from isettorch.camera import Camera
from isettorch.data import generate_scene
from isettorch.optics import DiffractionLimitedOptics
from isettorch.sensor import Sensor


def _scene():
    return generate_scene(3, seed=0, config={"height": 48, "width": 48}, dtype=torch.float64)  # factored


def _project(oi):
    # the factored optical image's irradiance, projected on a flat weighting (its photon sum per pixel)
    return oi.project(torch.ones(oi.wavelengths_nm.numel(), 1, dtype=torch.float64))


def test_repeated_calls_equal_a_fresh_module_exactly():
    sc = _scene()
    optics = DiffractionLimitedOptics(f_number=4.0)
    first, second = _project(optics(sc)), _project(optics(sc))  # a miss, then a hit of the memo
    fresh = _project(DiffractionLimitedOptics(f_number=4.0)(sc))
    assert torch.equal(first, second) and torch.equal(first, fresh)
    assert torch.equal(optics(sc).hfov_deg, DiffractionLimitedOptics(f_number=4.0)(sc.to_dense()).hfov_deg)


def test_memo_follows_a_replaced_f_number():
    sc = _scene()
    optics = DiffractionLimitedOptics(f_number=4.0)
    f4 = _project(optics(sc))
    # a new parameter object starts a new version counter: the memo must key on the value
    optics.f_number = nn.Parameter(torch.tensor(8.0, dtype=torch.float64), requires_grad=False)
    f8 = _project(optics(sc))
    assert torch.equal(f8, _project(DiffractionLimitedOptics(f_number=8.0)(sc)))
    # f/8 blurs more and gathers 4x less light (camera equation ~ 1 / N^2): the result changed
    ratio = float(f4.sum() / f8.sum())
    assert abs(ratio - (1 + 4 * 8.0**2) / (1 + 4 * 4.0**2)) < 1e-3 * ratio


def test_camera_window_follows_the_sensor_pitch():
    sc = _scene()
    optics = DiffractionLimitedOptics(f_number=4.0)
    sensor = Sensor(rows=8, cols=8, pixel_size_m=2.8e-6, exposure_s=0.01)
    cam = Camera(optics, sensor)
    w1 = cam.sensor_window(sc)
    assert cam.sensor_window(sc) == w1
    sensor.pixel_size_m = 1.4e-6
    w2 = cam.sensor_window(sc)
    fresh = Camera(optics, Sensor(rows=8, cols=8, pixel_size_m=1.4e-6, exposure_s=0.01)).sensor_window(sc)
    assert w2 == fresh and w2 != w1
