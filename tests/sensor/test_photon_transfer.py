"""Photon transfer (EMVA 1288 release 4.0): frames simulated at 22 exposure levels recover the configured
conversion gain, read noise, DSNU and PRNU within 2 %."""

import torch

from isettorch.metrics.emva import emva1288
from isettorch.optics import OpticalImage
from isettorch.sensor import CFA, Sensor, SpectralQE

W3 = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)


def test_photon_transfer_recovers_configuration():
    torch.set_num_threads(1)
    cg, read_v, dsnu_v, prnu_pct = 1e-4, 1e-3, 2e-3, 1.0
    bits, black = 16, 2000
    n = 128
    cfa = CFA("mono")
    sensor = Sensor(rows=n, cols=n, pixel_size_m=2e-6, fill_factor=1.0, cfa=cfa,
                    spectral_qe=SpectralQE(torch.full((1, 3), 0.5, dtype=torch.float64), W3, ["W"]),
                    conversion_gain_v_per_e=cg, voltage_swing_v=1.0, adc_bits=bits, black_level_dn=black,
                    shot_noise="poisson", read_noise_v=read_v, dark_current_e_per_s=5.0, dsnu_sigma_v=dsnu_v,
                    prnu_sigma_percent=prnu_pct, seed=11)
    frames = 6
    # irradiance giving 1e5 e-/s per pixel: the 10 000 e- well fills in 0.1 s
    level = 1e5 / (0.5 * 100 * 3 * (2e-6) ** 2)
    bright_oi = OpticalImage(torch.full((frames, 3, n + 8, n + 8), level, dtype=torch.float64), W3,
                             sample_spacing_m=2e-6)
    dark_oi = bright_oi.replace(photons=torch.zeros_like(bright_oi.photons))
    g = torch.Generator().manual_seed(5)
    exposures = torch.linspace(0.002, 0.115, 22, dtype=torch.float64)
    bright, dark = [], []
    for t in exposures:
        bright.append(sensor(bright_oi, exposure_s=t, generator=g).data[:, 0])
        dark.append(sensor(dark_oi, exposure_s=t, generator=g).data[:, 0])
    res = emva1288(torch.stack(bright), torch.stack(dark))
    lsb = sensor.lsb_v
    assert lsb == 1.0 / 2**bits
    got_cg = float(res.system_gain_dn_per_e) * lsb  # K (DN/e-) x LSB (V/DN)
    got_read = float(res.dark_noise_e) * cg
    got_dsnu = float(res.dsnu1288_e) * cg
    got_prnu = float(res.prnu1288_percent)
    assert abs(got_cg / cg - 1) < 0.02, got_cg
    assert abs(got_read / read_v - 1) < 0.02, got_read
    assert abs(got_dsnu / dsnu_v - 1) < 0.02, got_dsnu
    assert abs(got_prnu / prnu_pct - 1) < 0.02, got_prnu
