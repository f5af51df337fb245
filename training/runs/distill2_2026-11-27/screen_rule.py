"""Shipping screen for the second distillation run (configs/train/demosaic_noise_free_distill2.yaml), written on
2026-11-27 at about 01:00 UTC, before the run was started (so before any of its checkpoints existed). The same rule and
sets as the first distillation run's screen (training/runs/distill_2026-11-27/screen_rule.py).

Incumbent: the shipped distilled network (out/train_demosaic_noise_free_distill/best.pt), one pass.
Candidate: out/train_demosaic_noise_free_distill2/best.pt, one pass (``--candidate`` overrides it for a dry run).
Sets (24 x 256 px each, crop 10, RGGB): out/heldout_v5, out/heldout_v5_stress, out/heldout_stress and
out/heldout_v5_relgrain. Score: the mean of the four means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its four means is more than 0.05 dB below the
incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Kodak/McMaster and the scikit-image photos are scored afterwards, for reporting only.
"""
import sys

sys.path.insert(0, ".")
from training.heldout_screen import run_rule  # noqa: E402

SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain"]
INCUMBENT = "out/train_demosaic_noise_free_distill/best.pt"

if __name__ == "__main__":  # [--candidate PATH] for a dry run of this script
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_distill2/best.pt", SETS,
                              "training/runs/distill2_2026-11-27/screen_heldout.json",
                              "out/distill2_screen_dryrun.json"))
