"""How well does the held-out synthetic screen predict the photographs? For every noise-free 64 x 13 checkpoint on
disk: the mean CPSNR on the held-out v5 set (24 x 256 px, crop 10) against Kodak and McMaster (crop 10), and the
rank (Spearman) and linear (Pearson) correlations, separately for the 18 short ablation runs (1500 steps, two seeds,
`benchmarks/GENERATOR_ABLATION.md`; their Kodak/McMaster are read from their scores.json) and the long runs.
Reporting only: it changes no rule and selects nothing (a screen tuned to agree with Kodak would be selection on it)."""
import glob
import json
import os

import torch
from scipy.stats import pearsonr, spearmanr

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model, load_images

LONG = ["", "_finetune", "_stage3", "_stage4", "_stage5", "_dye", "_relgrain"]

if __name__ == "__main__":
    torch.set_num_threads(2)
    root = os.environ["ISETTORCH_DATA"]
    held = load_images("out/heldout_v5")
    rows = []
    for d in sorted(glob.glob("out/abl5/seed*/*/")):
        s = json.load(open(d + "scores.json"))
        h = evaluate_demosaic(held, model=load_demosaic_model(d + "best.pt"), crop=10)["mean_cpsnr"]
        rows.append({"group": "ablation", "run": d, "heldout_v5": h, "kodak": s["kodak"], "mcmaster": s["mcmaster"]})
        print(rows[-1], flush=True)
    for r in LONG:
        net = load_demosaic_model(f"out/train_demosaic_noise_free{r}/best.pt")
        row = {"group": "long", "run": f"noise_free{r}"}
        row["heldout_v5"] = evaluate_demosaic(held, model=net, crop=10)["mean_cpsnr"]
        for b, k in (("kodak24", "kodak"), ("mcmaster18", "mcmaster")):
            row[k] = evaluate_demosaic(f"{root}/{b}", model=net, crop=10)["mean_cpsnr"]
        rows.append(row)
        print(row, flush=True)
    summary = {}
    for g in ("ablation", "long"):
        sub = [r for r in rows if r["group"] == g]
        h = [r["heldout_v5"] for r in sub]
        for k in ("kodak", "mcmaster"):
            y = [r[k] for r in sub]
            summary[f"{g}/{k}"] = {"n": len(sub), "spearman": spearmanr(h, y)[0], "pearson": pearsonr(h, y)[0]}
    print(json.dumps(summary, indent=1))
    json.dump({"rows": rows, "summary": summary}, open("training/runs/relgrain_2026-11-26/screen_validity.json", "w"),
              indent=1)
