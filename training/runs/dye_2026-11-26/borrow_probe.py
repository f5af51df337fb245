"""Which channel's grain leaks into which channel's estimate? On the 24 held-out v5 stress scenes (green and blue
x 0.15 plus independent grain, std 0.005) the grain is the stress image minus the same scene without grain
(`out/heldout_v5_sat`). At the sites of the RGGB mosaic where channel s was sampled, its sample carries s's grain,
which is independent of the other channels' truth there; an estimator that transfers s's detail into channel c
makes c's error there correlate with s's grain. Reported: the least-squares slope of c's error on s's grain at
s's sites (0: nothing transferred). Malvar-He-Cutler transfers by design (fixed fractions of the sampled channel's
Laplacian: Malvar, He & Cutler, ICASSP 2004). Diagnostic, not a selection (no test set is read)."""
import json

import torch

from isettorch.isp.demosaicing import bayer_index_map, demosaic, mosaic
from isettorch.isp.evaluation import load_demosaic_model, load_images
from isettorch.isp.learned import demosaic_learned
from isettorch.sensor.cfa import tile

SUFFIXES = {"stage1 (v4, no grain)": "", "stage3": "_stage3", "stage5": "_stage5", "dye": "_dye",
            "relgrain": "_relgrain"}
RUNS = {k: f"out/train_demosaic_noise_free{r}/best.pt" for k, r in SUFFIXES.items()}


def probe(runs: dict, out: str, sat_dir: str = "out/heldout_v5_sat", stress_dir: str = "out/heldout_v5_stress") -> dict:
    """Transfer slopes {method: {"S_grain_into_C": slope}} for MHC and the checkpoints ``runs`` (name -> path)."""
    torch.set_num_threads(2)
    nets = {k: load_demosaic_model(p) for k, p in runs.items()}
    crop = 10
    pairs = [(s, c) for s in range(3) for c in range(3) if s != c]
    acc = {m: {p: [0.0, 0.0] for p in pairs} for m in ("malvar2004", *nets)}
    for (n1, sat), (n2, st) in zip(load_images(sat_dir), load_images(stress_dir)):
        assert n1 == n2
        sat_t = torch.tensor(sat, dtype=torch.float64).permute(2, 0, 1) / 255
        st_t = torch.tensor(st, dtype=torch.float64).permute(2, 0, 1) / 255
        grain = (st_t - sat_t)[:, crop:-crop, crop:-crop]
        raw = mosaic(st_t[None].float(), "RGGB")
        h, w = st_t.shape[-2:]
        idx = tile(bayer_index_map("RGGB"), h, w)[crop:-crop, crop:-crop]
        outs = {"malvar2004": demosaic(raw, "RGGB", "malvar2004")[0].double(),
                **{k: demosaic_learned(raw, "RGGB", model=n)[0].double().detach() for k, n in nets.items()}}
        for m, o in outs.items():
            err = (o - st_t)[:, crop:-crop, crop:-crop]
            for s, c in pairs:
                x, y = grain[s][idx == s], err[c][idx == s]
                acc[m][s, c][0] += float((x * y).sum())
                acc[m][s, c][1] += float((x * x).sum())
    res = {m: {f"{'RGB'[s]}_grain_into_{'RGB'[c]}": v[0] / v[1] for (s, c), v in d.items()} for m, d in acc.items()}
    for m, d in res.items():
        print(f"{m:22s} " + " ".join(f"{k} {v:+.3f}" for k, v in d.items()))
    with open(out, "w") as f:
        json.dump(res, f, indent=1)
    return res


if __name__ == "__main__":
    probe(RUNS, "training/runs/dye_2026-11-26/borrow_probe.json")
