"""Shipping screen for the dyed-materials run (configs/train/demosaic_noise_free_dye.yaml), written at 15:46 UTC on
2026-11-26, after the run started and before any of its checkpoints was scored (its own validation log aside), on
these sets or on Kodak/McMaster.

Incumbent: stage 3 (out/train_demosaic_noise_free_stage3/best.pt), which the weight-interpolation screen
(training/runs/soup_2026-11-26/soup_rule.py) chose over stage 5 by the rule fixed there.
Candidate: out/train_demosaic_noise_free_dye/best.pt.
Sets: out/heldout_v5, out/heldout_v5_stress, out/heldout_stress (24 x 256 px each, crop 10, RGGB); score = the mean
of the three means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its three means is more than 0.05 dB below
the incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Kodak/McMaster are scored afterwards, for reporting only.
The code was refactored later the same day to call training/heldout_screen.py (one implementation of the rule);
the rule, sets and output are unchanged (re-run: the same means and decision).
"""
import json
import sys

import torch

sys.path.insert(0, ".")
from training.heldout_screen import screen  # noqa: E402

SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress"]
PATHS = {"stage3": "out/train_demosaic_noise_free_stage3/best.pt", "dye": "out/train_demosaic_noise_free_dye/best.pt"}

if __name__ == "__main__":
    torch.set_num_threads(2)
    r = screen(PATHS["stage3"], PATHS["dye"], SETS)
    res = {"stage3": r["incumbent"], "dye": r["candidate"],
           "decision": "dye" if r["decision"] == "candidate" else "stage3"}
    for name in ("stage3", "dye"):
        row = res[name]
        print(name, " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in SETS), f"score {row['score']:.3f}")
    print("ship:", res["decision"])
    json.dump(res, open("training/runs/dye_2026-11-26/screen_heldout.json", "w"), indent=1)
