"""The optics' discrete Fourier blur rings below 0 next to black (its OTF is cut at the grid's Nyquist frequency); the
sensor's electron rates take those lobes to 0 and refuse anything deeper than ringing."""

import math

import pytest
import torch

from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import Scene
from isettorch.sensor import Sensor
from isettorch.sensor.sensor import RINGING_TOLERANCE

WL = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
N = 32


def _point_oi(f_number: float, pitch_m: float):
    """A point source (one bright sample on black) imaged at ``f_number`` on ``pitch_m`` samples."""
    maps = torch.zeros(1, 1, N, N, dtype=torch.float64)
    maps[0, 0, N // 2, N // 2] = 1.0
    hfov = math.degrees(2 * math.atan(pitch_m * N / (2 * 0.004)))
    scene = Scene.from_factors(maps, torch.full((1, 1, WL.numel()), 1e18, dtype=torch.float64), WL,
                               hfov_deg=hfov, distance_m=1e6)
    return DiffractionLimitedOptics(f_number=f_number, focal_length_m=0.004).double()(scene)


@pytest.mark.parametrize("f_number,pitch_m", [(2.8, 1.4e-6), (8.0, 2.8e-6), (2.0, 6e-6)])
def test_point_source_rings_below_zero_and_the_rates_clip_it(f_number, pitch_m):
    oi = _point_oi(f_number, pitch_m)
    cube = oi.photons
    lobe = float((cube.amin((-2, -1)) / cube.amax((-2, -1))).min())
    # the diffraction cut-off 1 / (lambda N) is beyond the grid's Nyquist frequency 1 / (2 pitch) at 400 nm: the
    # applied kernel is band-limited by the grid, and its lobes go below 0, but never deeper than the tolerance
    assert 1 / (400e-9 * f_number) > 1 / (2 * pitch_m)
    assert -RINGING_TOLERANCE < lobe < -1e-3
    sensor = Sensor(rows=N, cols=N, pixel_size_m=pitch_m, cfa="RGGB").double()
    rates, _ = sensor.channel_rates(oi)
    assert float(rates.min()) == 0.0
    # the rates are the projection of the ringing irradiance, clipped at 0: the same values wherever positive
    dense = sensor.sample(sensor.electron_rate_density(oi), oi) * sensor.fill_factor * sensor.pixel_area_m2
    assert float(dense.min()) < 0
    torch.testing.assert_close(rates, dense.clamp_min(0), rtol=1e-12, atol=0)


def test_no_ringing_when_the_cut_off_is_inside_the_grid():
    # f/4 on 0.8 um samples: the cut-off (625 cycles/mm at 400 nm, less at longer waves) is at most Nyquist (625)
    cube = _point_oi(4.0, 0.8e-6).photons
    assert float((cube.amin((-2, -1)) / cube.amax((-2, -1))).min()) > -1e-6


def test_rates_deeper_than_ringing_are_an_error():
    from isettorch.sensor.sensor import _without_ringing

    rates = torch.rand(2, 3, 8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) + 0.5
    assert _without_ringing(rates) is rates  # non-negative: untouched
    rates[1, 0, 0, 0] = -0.5 * RINGING_TOLERANCE * float(rates[1].max())
    out = _without_ringing(rates)
    assert float(out[1, 0, 0, 0]) == 0.0 and torch.equal(out[0], rates[0])
    rates[1, 0, 0, 0] = -0.2 * float(rates[1].max())  # 20 % of the peak below 0: no optics rings that deep
    with pytest.raises(ValueError, match="electron rates: expected non-negative"):
        _without_ringing(rates)
