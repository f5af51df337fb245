"""
Training a (tiny) demosaicker on simulated camera pairs
=======================================================

:class:`isettorch.data.camera_pairs.CameraPairDataset` renders random physical scenes (layouts, reflectances,
illuminants) through a full camera model and returns, for each item, the raw mosaic and the targets
(``camera_rgb``: the sensor's three channels at every pixel, without noise). A joint denoiser and
demosaicker learns noisy raw → camera_rgb. Here a two-layer network learns a residual on top of bilinear
interpolation, for 300 steps on 32 x 32 crops, and is compared with bilinear on held-out items (a different
dataset seed). Real training (``training/``) uses far more data and steps.
"""

import matplotlib.pyplot as plt
import torch
from torch import nn

from isettorch.data.camera_pairs import CameraPairDataset
from isettorch.isp import cpsnr, demosaic

torch.manual_seed(0)
scene = {"height": 32, "width": 32}
train = CameraPairDataset(64, seed=1, scene=scene, targets=("camera_rgb",)).get_batch(list(range(64)))
test = CameraPairDataset(16, seed=2, scene=scene, targets=("camera_rgb",)).get_batch(list(range(16)))
pattern = "RGGB"  # the datasets' CFA (meta["cfa"] holds its index map)


class ResidualDemosaic(nn.Module):
    """Bilinear demosaic plus a learned correction from the mosaic and the bilinear estimate. The last layer
    starts at zero, so training starts from bilinear."""

    def __init__(self, width: int = 16) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(4, width, 3, padding=1), nn.ReLU(), nn.Conv2d(width, 3, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, raw, base=None):
        base = demosaic(raw, pattern, method="bilinear") if base is None else base
        return base + self.net(torch.cat([raw, base], dim=1))


model = ResidualDemosaic()
opt = torch.optim.Adam(model.parameters(), lr=1e-3)
with torch.no_grad():  # bilinear does not learn: compute it once
    train_base = demosaic(train["raw"], pattern, method="bilinear")
losses = []
for _step in range(300):
    idx = torch.randint(0, 64, (16,))
    pred = model(train["raw"][idx], train_base[idx])
    loss = nn.functional.mse_loss(pred[..., 2:-2, 2:-2], train["camera_rgb"][idx][..., 2:-2, 2:-2])
    opt.zero_grad()
    loss.backward()
    opt.step()
    losses.append(loss.item())

with torch.no_grad():
    bilinear = demosaic(test["raw"], pattern, method="bilinear")
    learned = model(test["raw"])
psnr_bilinear = float(cpsnr(bilinear.clamp(0, 1), test["camera_rgb"], crop=2).mean())
psnr_learned = float(cpsnr(learned.clamp(0, 1), test["camera_rgb"], crop=2).mean())
print(f"held-out CPSNR: bilinear {psnr_bilinear:.2f} dB, learned {psnr_learned:.2f} dB")

fig, axes = plt.subplots(1, 4, figsize=(10, 2.8))
axes[0].semilogy(losses)
axes[0].set(title="training loss (MSE)", xlabel="step")
for ax, img, title in zip(axes[1:], (test["camera_rgb"], bilinear, learned),
                          ("target", f"bilinear {psnr_bilinear:.1f} dB", f"learned {psnr_learned:.1f} dB")):
    ax.imshow(img[0].permute(1, 2, 0).clamp(0, 1).pow(1 / 2.2).numpy())
    ax.set_title(title, fontsize=9)
    ax.axis("off")
fig.tight_layout()
