"""Gradient checks through the whole camera (scene -> diffraction-limited optics -> design sensor with noise), in
float64: autograd against central finite differences with common random numbers (the same generator seed for
every evaluation), for the filter parameters, the mosaic logits, the exposure and the f-number.

With reparameterised noise (Gaussian shot noise ``mu + sqrt(mu) z`` and Gaussian read noise, ``z`` fixed by the
seed) the noisy capture is a smooth function of the parameters, so finite differences of it must equal autograd.
Exact Poisson shot noise and the ADC's rounding are piecewise constant in the parameters; their straight-through
gradient is the gradient of the expected capture (E[Poisson(mu)] = mu), checked against finite differences of the
noise-free capture.
"""

from __future__ import annotations

import math

import pytest
import torch
from torch.func import functional_call

from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import Scene
from isettorch.sensor.design import design_sensor, fixed_design, learned_design

PITCH_M = 2.8e-6
FOCAL_M = 3.862755099e-3
DISTANCE_M = 1.2
ROWS = COLS = 6


def _scene(size: int = ROWS) -> Scene:
    """A factored 2-material scene, one sample per pixel (the FOV of training.camera_pairs' ``_set_fov``)."""
    g = torch.Generator().manual_seed(3)
    wl = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    maps = torch.rand(1, 2, size, size, generator=g, dtype=torch.float64) + 0.2
    spectra = (torch.rand(1, 2, wl.numel(), generator=g, dtype=torch.float64) + 0.5) * 2e15
    d_i = 1.0 / (1.0 / FOCAL_M - 1.0 / DISTANCE_M)
    hfov = math.degrees(2 * math.atan(PITCH_M * size / (2 * d_i)))
    return Scene.from_factors(maps, spectra, wl, hfov_deg=hfov, distance_m=DISTANCE_M)


def _camera(shot_noise: str, adc_bits=None, design: str = "learned"):
    if design == "learned":
        bank, mosaic = learned_design(("learned", "learned", "G", "W"), (2, 2), seed=1)
        mosaic.temperature = 0.7
        with torch.no_grad():  # logits of order 1: a softmax with every filter weighing in
            mosaic.logits.copy_(torch.randn(mosaic.logits.shape, generator=torch.Generator().manual_seed(5),
                                            dtype=torch.float64))
    else:
        bank, mosaic = fixed_design(design)
    sensor = design_sensor(bank, mosaic, rows=ROWS, cols=COLS, pixel_size_m=PITCH_M, fill_factor=0.9,
                           conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0, shot_noise=shot_noise,
                           read_noise_v=2e-3, dark_current_e_per_s=20.0, adc_bits=adc_bits)
    optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=FOCAL_M, learn_f_number=True)
    camera = torch.nn.ModuleDict({"optics": optics, "sensor": sensor}).train()
    return camera


def _capture(camera, scene, params: dict, exposure_s, *, noise: bool = True, seed: int = 11):
    """The raw capture (volts or DN) ``[B, 1, rows, cols]`` with ``params`` substituted (common random numbers:
    a fresh generator with the same seed on every call)."""
    optics = camera["optics"]
    sensor = camera["sensor"]
    g = torch.Generator().manual_seed(seed)
    oi = functional_call(optics, {k[len("optics."):]: v for k, v in params.items() if k.startswith("optics.")},
                         (scene,))
    sensor_params = {k[len("sensor."):]: v for k, v in params.items() if k.startswith("sensor.")}
    raw = functional_call(sensor, sensor_params, (oi,),
                          {"exposure_s": exposure_s, "generator": g, "noise": noise})
    return raw.data if noise else raw.noise_free


PARAMETERS = {
    "filter parameters": ("sensor.spectral_qe.raw_amplitudes", "sensor.spectral_qe.raw_offsets"),
    "mosaic logits": ("sensor.cfa.logits",),
    "f-number": ("optics.f_number",),
}


@pytest.mark.parametrize("group", [*PARAMETERS, "exposure"])
def test_autograd_matches_finite_differences_with_common_random_numbers(group):
    camera = _camera("gaussian")
    scene = _scene()
    base = {n: p.detach().clone() for n, p in camera.named_parameters()}
    exposure0 = torch.tensor([0.01], dtype=torch.float64)
    # the capture sits inside the sensor's linear range (no clipping at 0 or at the swing): smooth in every input
    v = _capture(camera, scene, base, exposure0)
    assert 0.02 < float(v.min()) and float(v.max()) < 0.9

    names = PARAMETERS.get(group, ())

    def f(*inputs):
        params = dict(base)
        params.update(zip(names, inputs[:len(names)]))
        t = inputs[-1] if group == "exposure" else exposure0
        return _capture(camera, scene, params, t)

    inputs = tuple(base[n].clone().requires_grad_(True) for n in names)
    if group == "exposure":
        inputs = (exposure0.clone().requires_grad_(True),)
    # eps: central differences in float64; the check compares every entry of the Jacobian
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-7, rtol=1e-4)
    # and the gradient is not trivially zero
    jac = torch.autograd.functional.jacobian(f, inputs)
    assert all(float(j.abs().max()) > 1e-4 for j in jac)


def test_the_noise_is_common_and_not_zero():
    """The check above is meaningful: with the same seed the noise repeats exactly, with another it differs by
    about its standard deviation (shot noise of a few thousand electrons and 2 mV read noise)."""
    camera = _camera("gaussian")
    scene = _scene()
    base = {n: p.detach() for n, p in camera.named_parameters()}
    t = torch.tensor([0.01], dtype=torch.float64)
    a = _capture(camera, scene, base, t, seed=11)
    b = _capture(camera, scene, base, t, seed=11)
    c = _capture(camera, scene, base, t, seed=12)
    clean = _capture(camera, scene, base, t, noise=False)
    assert torch.equal(a, b)
    resid = (a - clean).std() / 1e-4  # electrons
    assert float(resid) > 10  # several tens of electrons: noise is on
    assert float((a - c).abs().max()) > 0


@pytest.mark.parametrize("design", ["learned", "rgbw"])
def test_straight_through_gradient_is_the_gradient_of_the_expected_capture(design):
    """Exact Poisson shot noise and ADC rounding (10 bits): the autograd Jacobian of the noisy DN equals the
    finite-difference Jacobian of the noise-free capture (the mean) for the filters, logits and f-number."""
    camera = _camera("poisson", adc_bits=10, design=design)
    scene = _scene()
    base = {n: p.detach().clone() for n, p in camera.named_parameters()}
    names = [n for n, p in camera.named_parameters() if p.requires_grad]
    t = torch.tensor([0.01], dtype=torch.float64)

    def capture(noise):
        def f(*inputs):
            params = dict(base)
            params.update(zip(names, inputs))
            return _capture(camera, scene, params, t, noise=noise)
        return f

    inputs = tuple(base[n].clone() for n in names)
    noisy_jac = torch.autograd.functional.jacobian(capture(True), inputs)
    mean_jac = torch.autograd.functional.jacobian(capture(False), inputs)
    # the noisy capture really is noisy and rounded
    noisy, mean = capture(True)(*inputs), capture(False)(*inputs)
    assert float((noisy - noisy.round()).abs().max()) == 0 and float((noisy - mean).abs().max()) > 5
    for jn, jm in zip(noisy_jac, mean_jac):
        torch.testing.assert_close(jn, jm, rtol=1e-10, atol=1e-9)
    # the mean's autograd Jacobian against central differences, one direction per parameter tensor
    g = torch.Generator().manual_seed(7)
    for i, name in enumerate(names):
        d = torch.randn(inputs[i].shape, generator=g, dtype=torch.float64)
        eps = 1e-6
        plus = list(inputs)
        minus = list(inputs)
        plus[i] = inputs[i] + eps * d
        minus[i] = inputs[i] - eps * d
        fd = (capture(False)(*plus) - capture(False)(*minus)) / (2 * eps)
        ad = (mean_jac[i].reshape(*fd.shape, -1) * d.reshape(-1)).sum(-1)
        torch.testing.assert_close(ad, fd, rtol=1e-5, atol=1e-6 * float(fd.abs().max()))
        assert float(fd.abs().max()) > 0.1, name  # DN per unit parameter: a real dependence
