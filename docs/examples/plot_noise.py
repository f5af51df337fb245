"""
Sensor noise: photon transfer and SNR
=====================================

A uniform scene imaged at increasing exposures: the SNR of the raw pixels (mean / standard deviation over a
flat region, :func:`isettorch.metrics.snr_uniform`) follows the pixel noise model of EMVA 1288,
:math:`\\mathrm{SNR} = S / \\sqrt{S + \\sigma_r^2 + (p S)^2}` with :math:`S` the signal in electrons
(:func:`isettorch.metrics.pixel_snr`): read-noise limited in the dark, shot-noise limited (slope 1/2 on
log axes) in the mid-tones, PRNU limited near saturation.
"""

import matplotlib.pyplot as plt
import numpy as np
import torch

from isettorch.camera import Camera
from isettorch.isp import ImageProcessor
from isettorch.metrics import pixel_snr, snr_uniform
from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import uniform
from isettorch.sensor import Sensor

read_noise_e, prnu_percent, gain_v_per_e = 5.0, 1.0, 1e-4
sensor = Sensor(cfa="RGGB", conversion_gain_v_per_e=gain_v_per_e,
                voltage_swing_v=1.0, read_noise_v=read_noise_e * gain_v_per_e, prnu_sigma_percent=prnu_percent,
                output_units="electrons", seed=0)
cam = Camera(DiffractionLimitedOptics(f_number=4.0), sensor, ImageProcessor(), noise=True)
scene = uniform("D65", 64, hfov_deg=2.0)  # 2.1 µm samples: finer than the 2.8 µm pixels
exposures = np.geomspace(1e-3, 0.4, 14)  # signals from ~30 e- (above the clip at 0) to near full well
signal, measured = [], []
for t in exposures:
    raw = cam(scene, return_intermediates=True, exposure_s=float(t),
              generator=torch.Generator().manual_seed(1)).raw
    # One CFA channel of RGGB (G at even rows, odd columns), away from the blurred image border.
    green = raw.data[0, 0, 8:-8:2, 9:-8:2].double()
    s_e = float(raw.noise_free[0, 0, 8:-8:2, 9:-8:2].mean())
    if s_e < 0.9 * sensor.well_capacity_e:
        signal.append(s_e)
        measured.append(float(snr_uniform(green)))
signal = np.array(signal)
model = pixel_snr(torch.tensor(signal), read_noise_e=read_noise_e, prnu_percent=prnu_percent).numpy()

fig, ax = plt.subplots(figsize=(6, 4))
ax.loglog(signal, measured, "o", label="simulated (snr_uniform)")
ax.loglog(signal, model, "-", label="EMVA 1288 model (pixel_snr)")
ax.loglog(signal, np.sqrt(signal), ":", color="gray", label="shot-noise limit √S")
ax.set(xlabel="signal (electrons)", ylabel="SNR", title="Photon transfer: SNR against signal")
ax.legend()
fig.tight_layout()
rel = float(np.max(np.abs(np.array(measured) / model - 1)))
print(f"max relative difference simulated / model: {rel:.3f} (sampling error of a few hundred pixels)")
