"""
Synthesising a camera dataset
=============================

:class:`isettorch.data.camera_pairs.CameraPairDataset` is a map-style PyTorch dataset: item ``i`` depends only
on ``(seed, i)``, on any worker. Each item is a random physical scene (a layout of surfaces with measured-like
reflectances under one or two illuminants) rendered through the camera model: the noisy raw mosaic, the
noise-free raw, the sensor RGB, XYZ, linear and encoded sRGB, and the capture's metadata (exposure, gain,
noise parameters, CFA, illuminant). ``isettorch synth`` writes such a dataset to disk in shards.
"""

import matplotlib.pyplot as plt
import torch

from isettorch.data.camera_pairs import CameraPairDataset

ds = CameraPairDataset(6, seed=0, scene={"height": 64, "width": 64})
batch = ds.get_batch(list(range(6)))
print({k: tuple(v.shape) for k, v in batch.items() if isinstance(v, torch.Tensor)})
print("exposure (ms):", [round(float(t) * 1e3, 2) for t in batch["meta"]["exposure_s"]])
print("illuminant CCT (K):", [round(float(c)) for c in batch["meta"]["cct_k"]])

# Items are reproducible: the same (seed, index) gives the same pair.
assert torch.equal(ds.get_batch([3])["raw"][0], batch["raw"][3])

fig, axes = plt.subplots(2, 6, figsize=(11, 4))
for i in range(6):
    axes[0, i].imshow(batch["raw"][i, 0].clamp(0, 1).pow(1 / 2.2).numpy(), cmap="gray")
    axes[0, i].set_title(f"raw #{i}", fontsize=8)
    axes[1, i].imshow(batch["srgb"][i].permute(1, 2, 0).numpy())
    axes[1, i].set_title(f"sRGB, {float(batch['meta']['cct_k'][i]):.0f} K", fontsize=8)
for ax in axes.flat:
    ax.axis("off")
fig.tight_layout()
