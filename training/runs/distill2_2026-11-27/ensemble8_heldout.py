"""How much stronger would a larger geometric ensemble make the teacher? One pass, the two-pass transpose ensemble and
the eight-pass dihedral ensemble of stage 3 and of the shipped network (distill-2) on the four held-out synthetic sets
(24 x 256 px, crop 10), measured after distill-2 shipped, to plan the next distillation round (no test set is scored).

The dihedral ensemble is ``demosaic_learned(..., self_ensemble="dihedral")`` (`isettorch demosaic-eval
--dihedral-ensemble`): a flipped RGGB mosaic is demosaicked as the Bayer pattern it then has, with the transpose
ensemble, and flipped back; the eight outputs are averaged.
"""
import json

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

if __name__ == "__main__":
    torch.set_num_threads(2)
    nets = {"stage3": "out/train_demosaic_noise_free_stage3/best.pt",
            "distill2": "out/train_demosaic_noise_free_distill2/best.pt"}
    res = {}
    for name, path in nets.items():
        net = load_demosaic_model(path)
        for s in ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain"]:
            one = evaluate_demosaic(s, "learned", "RGGB", 10, model=net)["mean_cpsnr"]
            two = evaluate_demosaic(s, "learned", "RGGB", 10, model=net, self_ensemble=True)["mean_cpsnr"]
            eight = evaluate_demosaic(s, "learned", "RGGB", 10, model=net, self_ensemble="dihedral")["mean_cpsnr"]
            res.setdefault(name, {})[s] = {"one": one, "transpose2": two, "dihedral8": eight}
            print(name, s, f"{one:.3f} {two:.3f} {eight:.3f}", flush=True)
    json.dump(res, open("training/runs/distill2_2026-11-27/ensemble8_heldout.json", "w"), indent=1)
