"""
Designing a camera through its gradients: filters, mosaic and reconstruction
============================================================================

A sensor design is a bank of colour filters (:class:`isettorch.sensor.filter_bank.FilterBank`) and a mosaic that
gives each pixel one of them (:class:`isettorch.sensor.mosaic.LearnedMosaic`). Both are modules of the library's
:class:`~isettorch.sensor.Sensor`, so a capture has the sensor's photon noise, read noise, exposure and ADC, and
gradients reach the filters and the mosaic's logits. Learned filters are smooth by construction (a sigmoid of
raised-cosine bands: in [0, 1], slope at most 0.047 / nm); while learning, each mosaic pixel mixes the filters
with a softmax whose temperature falls; in eval mode the mosaic is hard, one filter per pixel.

Below: the three fixed designs of the comparison (Bayer RGB, the 2004 paper's YCMY, Kodak's RGBW with 50 % clear
pixels) and an untrained learned design; then one photograph rendered through each at 1 and 100 lux with the same
noise (the input a reconstruction network sees: the raw mosaic divided by a white card's reading); then a few
gradient steps of filters, mosaic and a tiny network together; last, filters designed on a physical criterion alone
(no network). ``training/codesign.py`` runs the real training and ``isettorch design-eval`` scores a design file on
photographs.
"""

import matplotlib.pyplot as plt
import numpy as np
import torch
from skimage import data as skdata

from isettorch.data.photos import lift_srgb
from isettorch.design import linear_srgb_of_reflectance, make_design, predesign_filters
from isettorch.sensor.mosaic import temperature_schedule

torch.manual_seed(0)
designs = {name: make_design(name, {"network": {"width": 8, "depth": 2}}, lux=(1, 100))
           for name in ("bayer_rgb", "ycmy", "rgbw")}
designs["learned"] = make_design({"filters": ["learned", "learned", "learned", "W"], "mosaic_shape": [4, 4]},
                                 {"network": {"width": 8, "depth": 2}}, lux=(1, 100))

# %%
# Filters and mosaics
# -------------------
fig, axes = plt.subplots(2, 4, figsize=(11, 4.6), gridspec_kw={"height_ratios": [3, 2]})
for k, (name, cam) in enumerate(designs.items()):
    bank, mosaic = cam.bank, cam.mosaic.eval()
    wl = bank.wavelengths_nm.numpy()
    for i, f in enumerate(bank.filters.detach().numpy()):
        axes[0, k].plot(wl, f, label=bank.channel_names[i])
    axes[0, k].set_title(name)
    axes[0, k].set_ylim(0, 1.02)
    axes[0, k].legend(fontsize=7)
    axes[1, k].imshow(mosaic.index_map.numpy(), cmap="tab10", vmin=0, vmax=9)
    for (r, c), v in np.ndenumerate(mosaic.index_map.numpy()):
        axes[1, k].text(c, r, bank.channel_names[v], ha="center", va="center", color="white", fontsize=8)
    axes[1, k].set_xticks([])
    axes[1, k].set_yticks([])
axes[0, 0].set_ylabel("transmittance")
fig.tight_layout()

# %%
# One photograph at 1 and 100 lux
# -------------------------------
# The photograph is the reflectance of a surface lit by D65 (Mallett & Yuksel's sRGB basis); the lens is f/2,
# the exposure at most 1/30 s, then analog gain up to 16. At 1 lux every design is photon-starved; the clear
# pixels of RGBW collect several times the photons of a colour pixel.
photo = skdata.astronaut()[40:104:2, 180:244:2]  # 32 x 32
lifted = lift_srgb(np.ascontiguousarray(photo))
fig, axes = plt.subplots(2, 4, figsize=(11, 5.6))
for k, (name, cam) in enumerate(designs.items()):
    cam.eval()
    for r, lux in enumerate((1.0, 100.0)):
        scene = cam.scene(lifted["maps"][None].float(), lifted["reflectance"].float(), lux)
        with torch.no_grad():
            cap = cam.capture(scene, generator=torch.Generator().manual_seed(1))
        axes[r, k].imshow(cap["input"][0, 0].clamp(0, 1.5).numpy(), cmap="gray", vmin=0, vmax=1.2)
        axes[r, k].set_title(f"{name}, {lux:g} lux\nt = {1e3 * float(cap['exposure_s'][0]):.1f} ms, "
                             f"gain {float(cap['analog_gain'][0]):.1f}", fontsize=8)
        axes[r, k].axis("off")
fig.tight_layout()

# %%
# A few gradient steps of the whole design
# ----------------------------------------
# The loss (L1 in linear sRGB against the photograph) reaches the filter bands, the mosaic logits and the
# network; the relaxed mosaic's temperature falls as in training.
cam = designs["learned"].train()
rgb = linear_srgb_of_reflectance(lifted["reflectance"], lifted["wavelengths_nm"]).float()  # [3 maps, 3]
target = torch.einsum("jc,jhw->chw", rgb, lifted["maps"].float())[None]
opt = torch.optim.Adam([{"params": cam.networks.parameters(), "lr": 3e-3},
                        {"params": [p for n, p in cam.named_parameters()
                                    if p.requires_grad and not n.startswith("networks.")], "lr": 5e-2}])
before = cam.bank.filters.detach().clone()
losses = []
for step in range(30):
    cam.mosaic.temperature = temperature_schedule(step, 30, 1.0, 0.1)
    scene = cam.scene(lifted["maps"][None].float(), lifted["reflectance"].float(), 100.0)
    out = cam(scene, 100.0, generator=torch.Generator().manual_seed(step))
    loss = (out - target).abs().mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
    losses.append(loss.item())
fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.2))
a.plot(losses)
a.set_xlabel("step")
a.set_ylabel("L1 loss")
wl = cam.bank.wavelengths_nm.numpy()
for i in range(3):
    line, = b.plot(wl, before[i].numpy(), ":")
    b.plot(wl, cam.bank.filters.detach()[i].numpy(), color=line.get_color(), label=cam.bank.channel_names[i])
b.set_title("learned filters: before (dotted) and after 30 steps", fontsize=9)
b.legend(fontsize=7)
fig.tight_layout()
print(f"loss {losses[0]:.3f} -> {losses[-1]:.3f}; mosaic now {cam.mosaic.eval().cell}")

# %%
# Filters designed on the noise-limited colour estimate
# -----------------------------------------------------
# Before any network trains, the shipped learned design's filters were set by
# :func:`isettorch.design.predesign_filters`: Adam on the error of the best linear colour estimate from a patch's
# channel means over 16 pixels, with the capture's own photon, read, dark and ADC noise, the colour correction
# fitted on the scene generator's materials and scored on the Macbeth chart and on colours lifted as photographs
# are. Here 20 steps at 1 lux, on smaller sets of materials than the shipped run's, from band-pass filters in
# Bayer's layout; ``gain_db`` is the criterion's gain over Bayer's filters in the same camera.
cam = make_design({"filters": ["learned"] * 3, "mosaic_shape": [2, 2], "mosaic_init": [["F1", "F0"], ["F2", "F1"]]})
start = cam.bank.filters.detach().clone()
record = predesign_filters(cam, [1.0], steps=20, fit_patches=64, test_colours=32)
fig, ax = plt.subplots(figsize=(5, 3.2))
wl = cam.bank.wavelengths_nm.numpy()
for i in range(3):
    line, = ax.plot(wl, start[i].numpy(), ":")
    ax.plot(wl, cam.bank.filters.detach()[i].numpy(), color=line.get_color(), label=cam.bank.channel_names[i])
ax.set_title(f"predesign at 1 lux: {record['gain_db']['1']:+.2f} dB over Bayer (dotted: start)", fontsize=9)
ax.set_xlabel("wavelength (nm)")
ax.legend(fontsize=7)
fig.tight_layout()
print(record["gain_db"])
