"""Where is stage 3's extra error on the stress scenes: at the sites where a channel was sampled (where the truth is
in the mosaic: Malvar-He-Cutler passes it through, error 0) or where it was not? Per-channel MSE on the 24 held-out
v5 scenes with and without grain (gains-only `out/heldout_v5_sat`, stress `out/heldout_v5_stress`), split by site.
Diagnostic, not a selection (no test set is read)."""
import json

import torch

from isettorch.isp.demosaicing import bayer_index_map, demosaic, mosaic
from isettorch.isp.evaluation import load_demosaic_model, load_images
from isettorch.isp.learned import demosaic_learned
from isettorch.sensor.cfa import tile

torch.set_num_threads(2)
net = load_demosaic_model("out/train_demosaic_noise_free_stage3/best.pt")
crop = 10
res = {}
for name, folder in (("gains only", "out/heldout_v5_sat"), ("stress", "out/heldout_v5_stress")):
    sums = {m: torch.zeros(3, 2, dtype=torch.float64) for m in ("malvar2004", "stage3")}  # [channel, sampled?]
    count = torch.zeros(3, 2, dtype=torch.float64)
    for _, im in load_images(folder):
        t = torch.tensor(im, dtype=torch.float64).permute(2, 0, 1) / 255
        raw = mosaic(t[None].float(), "RGGB")
        h, w = t.shape[-2:]
        idx = tile(bayer_index_map("RGGB"), h, w)[crop:-crop, crop:-crop]
        outs = {"malvar2004": demosaic(raw, "RGGB", "malvar2004")[0].double(),
                "stage3": demosaic_learned(raw, "RGGB", model=net)[0].double().detach()}
        for c in range(3):
            sampled = idx == c
            for s, mask in ((1, sampled), (0, ~sampled)):
                count[c, s] += mask.sum()
                for m, o in outs.items():
                    e = (o[c] - t[c])[crop:-crop, crop:-crop]
                    sums[m][c, s] += (e[mask] ** 2).sum()
    # contribution of each (channel, site kind) to the mean CPSNR error: sum of squares / (3 x pixels)
    total = count.sum()
    res[name] = {m: {f"{'RGB'[c]}_{'sampled' if s else 'missing'}": float(v[c, s] / total * 1e4)
                     for c in range(3) for s in (1, 0)} for m, v in sums.items()}
    for m, d in res[name].items():
        print(f"{name:10s} {m:10s} " + " ".join(f"{k} {v:.3f}" for k, v in d.items()), flush=True)
print("(x 1e-4: each entry's share of the pooled MSE)")
json.dump(res, open("training/runs/dye_2026-11-26/site_probe.json", "w"), indent=1)
