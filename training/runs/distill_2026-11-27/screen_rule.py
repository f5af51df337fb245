"""Shipping screen for the self-ensemble distillation run (configs/train/demosaic_noise_free_distill.yaml), written on
2026-11-26 at about 23:13 UTC, before the run was started (so before any of its checkpoints existed). The same rule and
sets as the relative-grain run's screen (training/runs/relgrain_2026-11-26/screen_rule.py); the candidate's
generator is version 5 with its defaults, so no new set is drawn for it.

Incumbent: stage 3 (out/train_demosaic_noise_free_stage3/best.pt, the shipped model), one pass.
Candidate: out/train_demosaic_noise_free_distill/best.pt, one pass (``--candidate`` overrides it for a dry run).
Sets (24 x 256 px each, crop 10, RGGB): out/heldout_v5, out/heldout_v5_stress, out/heldout_stress and
out/heldout_v5_relgrain (training/make_heldout.py; commands in the relgrain and stage-5 screen rules).
Score: the mean of the four means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its four means is more than 0.05 dB below the
incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Reference, not part of the rule: the teacher's own two-pass self-ensemble on the same sets (39.972, 36.965, 37.267,
36.396; out/s30/ens_heldout.py of 2026-11-26), the ceiling a one-pass student taught by it can approach.
Kodak/McMaster and the scikit-image photos are scored afterwards, for reporting only.
"""
import sys

sys.path.insert(0, ".")
from training.heldout_screen import run_rule  # noqa: E402

SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain"]
INCUMBENT = "out/train_demosaic_noise_free_stage3/best.pt"

if __name__ == "__main__":  # [--candidate PATH] for a dry run of this script
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_distill/best.pt", SETS,
                              "training/runs/distill_2026-11-27/screen_heldout.json",
                              "out/distill_screen_dryrun.json"))
