"""
PSF and MTF of a diffraction-limited lens
=========================================

The optics' point-spread function and modulation transfer come from the same OTF the optics apply to an
image (:mod:`isettorch.optics.analysis`). For a diffraction-limited lens the MTF is known in closed form
(Goodman, *Introduction to Fourier Optics*, eq. 6-32):

.. math:: \\mathrm{MTF}(\\nu) = \\frac{2}{\\pi}\\left(\\arccos s - s\\sqrt{1 - s^2}\\right),\\quad s = \\nu\\lambda N,

and the PSF is the Airy pattern with its first zero at :math:`1.22\\,\\lambda N`.
"""

import math

import matplotlib.pyplot as plt
import numpy as np
import torch

from isettorch.optics import DiffractionLimitedOptics, analysis

fig, (ax_psf, ax_mtf) = plt.subplots(1, 2, figsize=(9, 3.6))
for n, colour in ((2.8, "C0"), (8.0, "C1")):
    optics = DiffractionLimitedOptics(f_number=n)
    spacing = 0.1e-6
    psf = analysis.psf(optics, torch.tensor([550.0]), spacing, size=256)[0, 0]
    x_um = (np.arange(256) - 128) * spacing * 1e6
    ax_psf.plot(x_um, psf[128].numpy() / float(psf.max()), colour, label=f"f/{n:g}")
    ax_psf.axvline(1.22 * 0.55 * n, color=colour, ls=":")  # first Airy zero, µm
    nu = np.linspace(0, 1 / (550e-9 * n), 200)
    mtf = analysis.mtf(optics, torch.tensor([550.0]), torch.from_numpy(nu))[0, 0].numpy()
    s = nu * 550e-9 * n
    closed_form = 2 / math.pi * (np.arccos(s) - s * np.sqrt(1 - s ** 2))
    ax_mtf.plot(nu * 1e-3, mtf, colour, label=f"f/{n:g}")
    ax_mtf.plot(nu * 1e-3, closed_form, "k--", lw=0.8)
    print(f"f/{n:g}: max |MTF - closed form| = {np.abs(mtf - closed_form).max():.2e}")
ax_psf.set(xlim=(-12, 12), xlabel="µm", ylabel="PSF (peak 1)", title="PSF cross-section at 550 nm")
ax_mtf.set(xlabel="cycles/mm", ylabel="MTF", title="MTF at 550 nm (dashed: closed form)")
ax_psf.legend()
ax_mtf.legend()
fig.tight_layout()
