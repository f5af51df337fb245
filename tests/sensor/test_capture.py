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
