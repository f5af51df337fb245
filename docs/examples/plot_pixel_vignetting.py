"""
Pixel vignetting and microlenses
================================

The light a pixel collects depends on the angle at which the lens's chief ray arrives (Catrysse & Wandell,
"Optical efficiency of image sensor pixels", JOSA A 2002; the pixel-vignetting analysis of Farrell et al., SPIE
2004). :mod:`isettorch.sensor.microlens` is ISET's microlens model (ISETCam ``mlRadiance``): rays in 1-D phase
space through the microlens, its offset and the layers of the stack, to the photodiode.

Top left: the etendue (the fraction of the pixel's light reaching the photodiode) of ISETCam's default pixel
(2.8 µm, 7 µm stack, microlens f = 7 µm at f/2.5, an f/4 lens) for the three cases of ``mlAnalyzeArrayEtendue``;
dots are ISETCam's own 255 x 255 grid (``sampling="isetcam"``, the default: ISETCam's numbers, printed below),
lines the exact integral of the same model (``sampling="continuous"``, differentiable, within ~0.02 of the grid
here). A centred microlens collects everything on axis and nothing beyond ~24 deg; shifted to its optimal offset it
collects everything.

Top right: the optimal microlens offset across a sensor with a 30 deg field of view (ISETCam
``mlOptimalOffsets``): the microlens array is shrunk towards the centre.

Bottom: a small (1.4 µm) and a large (2.8 µm) pixel under the same 7 µm stack and microlens focal length: the
small pixel's acceptance angle is narrower (its centred etendue halves by ~10 deg instead of ~15 deg), and with
diffraction (``diffraction=True``, a ``sampling="continuous"`` option) red light spills out of the small photodiode
more than blue, which the camera shows as colour shading towards the corners (``Sensor(pixel_optics=...)``).
"""

import math

import matplotlib.pyplot as plt
import numpy as np
import torch

from isettorch.sensor.microlens import ISETCAM_PIXEL, microlens_array_offsets_m, microlens_etendue

cra = torch.linspace(0, 35, 71)
coarse = torch.arange(0.0, 35.1, 5.0)
fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
ax = axes[0, 0]
for method, colour in (("none", "C0"), ("centred", "C1"), ("optimal", "C2")):
    ax.plot(cra, microlens_etendue(cra, method, sampling="continuous"), colour, label=method)
    grid = microlens_etendue(coarse, method)  # ISETCam's grid (sampling="isetcam")
    ax.plot(coarse, grid, colour + "o", ms=4)
    print(f"{method:8s}", " ".join(f"{v:.3f}" for v in grid.tolist()))
ax.set(xlabel="chief-ray angle (deg)", ylabel="etendue", title="ISETCam default pixel (dots: ISETCam grid)")
ax.legend()

# the optimal offsets over a 30 deg sensor behind ISETCam's default 3.86 mm lens
f_src = ISETCAM_PIXEL["source_focal_length_m"]
cols = 2 * round(f_src * math.tan(math.radians(15)) / 2.8e-6)
rows = round(cols * 0.75)
offsets = microlens_array_offsets_m(rows, cols, 2.8e-6)
im = axes[0, 1].imshow(offsets.numpy() * 1e6, cmap="viridis")
fig.colorbar(im, ax=axes[0, 1], label="µm")
axes[0, 1].set(title=f"optimal offset, {rows} x {cols} px, 30 deg FOV", xticks=[], yticks=[])

for ax, (pitch, title) in zip(axes[1], ((2.8e-6, "2.8 µm pixel"), (1.4e-6, "1.4 µm pixel"))):
    pix = dict(pixel_size_m=pitch, photodiode_size_m=pitch * math.sqrt(0.75), microlens_diameter_m=pitch)
    for method, ls in (("centred", "-"), ("optimal", "--")):
        for wl, colour in ((450.0, "b"), (650.0, "r")):
            e = microlens_etendue(cra, method, sampling="continuous", diffraction=True, wavelength_nm=wl, **pix)
            ax.plot(cra, e, colour + ls, label=f"{method}, {wl:.0f} nm")
    ax.set(xlabel="chief-ray angle (deg)", ylabel="etendue", ylim=(0, 1.05), title=f"{title}, 7 µm stack")
axes[1, 0].legend(fontsize=8)
fig.tight_layout()
small = microlens_etendue(torch.tensor([0.0]), "centred", sampling="continuous", diffraction=True,
                          wavelength_nm=torch.tensor([450.0, 650.0]), pixel_size_m=1.4e-6,
                          photodiode_size_m=1.4e-6 * math.sqrt(0.75), microlens_diameter_m=1.4e-6)
print("1.4 um pixel on axis, 450 / 650 nm:", np.round(small.numpy(), 3))
plt.show()
