"""Sensor.capture: the capture from a precomputed electron rate is exactly what forward does after electron_rate."""

import pytest
import torch

from isettorch.optics.optical_image import OpticalImage
from isettorch.sensor import Sensor


def _sensor(**kw):
    return Sensor(rows=6, cols=8, pixel_size_m=2e-6, cfa="RGGB", adc_bits=10, black_level_dn=16,
                  read_noise_v=2e-3, dark_current_e_per_s=30.0, dsnu_sigma_v=1e-3, prnu_sigma_percent=1.0,
                  fpn_mode="per_frame", **kw)


def test_capture_equals_forward_bitwise():
    g = torch.Generator().manual_seed(0)
    oi = OpticalImage(torch.rand(2, 7, 12, 16, generator=g, dtype=torch.float64) * 1e16,
                      torch.arange(400.0, 701.0, 50.0, dtype=torch.float64), sample_spacing_m=1e-6)
    s = _sensor()
    a = s(oi, exposure_s=0.01, analog_gain=2.0, generator=torch.Generator().manual_seed(3))
    b = s.capture(s.electron_rate(oi), exposure_s=0.01, analog_gain=2.0, generator=torch.Generator().manual_seed(3))
    assert torch.equal(a.data, b.data) and torch.equal(a.noise_free, b.noise_free)
    # noise-free, 1 e-/s for 0.5 s at conversion gain 1e-4 V/e-, 10 bits over 1 V: 0.5e-4 / (1 / 1024) DN + black
    clean = s.capture(torch.ones(1, 1, 6, 8, dtype=torch.float64), exposure_s=0.5, noise=False).noise_free
    torch.testing.assert_close(clean, torch.full_like(clean, 0.5e-4 * 1024 + 16))


def test_capture_rejects_bad_rates_and_missing_auto_exposure():
    s = _sensor()
    with pytest.raises(ValueError, match="electron_rate"):
        s.capture(torch.ones(1, 3, 6, 8), exposure_s=0.01)
    with pytest.raises(ValueError, match="electron_rate"):
        s.capture(-torch.ones(1, 1, 6, 8), exposure_s=0.01)
    with pytest.raises(ValueError, match="exposure_s"):
        _sensor(auto_exposure="mean").capture(torch.ones(1, 1, 6, 8))


def test_nearly_black_captures_have_finite_float32_gradients():
    """d(1 / x) / dx = -1 / x^2 overflows float32 below x ~ 5e-20: auto-exposure's capped exposure (gradient 0)
    gave 0 x inf = NaN for a statistic of 1e-25 V/s, and the ISP's max / percentile scaling NaN gradients to a
    1e-20 cd/m^2 scene. Now the capped exposure's gradient is exactly 0, and a camera's float32 gradient to the scene
    is finite and agrees with float64's."""
    import warnings

    from isettorch import Camera, scene
    from isettorch.scene import Scene
    from isettorch.sensor.exposure import auto_exposure

    v = torch.full((1, 1, 2, 2), 1e-25, requires_grad=True)
    t = auto_exposure(v, 1.0)
    t.sum().backward()
    assert float(t.detach()) == 10.0 and torch.equal(v.grad, torch.zeros_like(v))
    for config in ("default", "paper2004_cds"):  # auto-exposure; a fixed exposure with percentile scaling
        grads = {}
        for dtype in (torch.float32, torch.float64):
            cam = Camera.from_config(config)
            cam.noise = False
            cam.sensor.rows = cam.sensor.cols = 16
            s0 = scene.macbeth(patch_size=8, mean_luminance_cd_m2=1e-20, dtype=dtype)
            ph = s0.photons.detach().clone().requires_grad_(True)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                img = cam(Scene(ph, s0.wavelengths_nm, hfov_deg=s0.hfov_deg, distance_m=s0.distance_m))
            weights = torch.linspace(0, 1, img.numel(), dtype=dtype).reshape(img.shape)
            (img * weights).sum().backward()
            grads[dtype] = (ph.grad * ph).detach().double()  # (relative sensitivities: O(1) to O(1e-19))
        assert torch.isfinite(grads[torch.float32]).all(), config
        scale = grads[torch.float64].abs().max()
        assert float(scale) > 0
        assert float((grads[torch.float32] - grads[torch.float64]).abs().max()) <= 1e-3 * float(scale), config
