"""Shipping screen for the multiplicative-grain run (configs/train/demosaic_noise_free_relgrain.yaml), written on
2026-11-26 at about 20:10 UTC, before the run was started (so before any of its checkpoints existed). It follows the
proposal of the stop-27 note: the held-out sets also include one drawn with the candidate's generator options.

Incumbent: stage 3 (out/train_demosaic_noise_free_stage3/best.pt, the shipped model).
Candidate: out/train_demosaic_noise_free_relgrain/best.pt (``--candidate`` overrides it for a dry run of this script).
Sets (24 x 256 px each, crop 10, RGGB): out/heldout_v5, out/heldout_v5_stress, out/heldout_stress and
out/heldout_v5_relgrain, made by
    python training/make_heldout.py --out out/heldout_v5_relgrain --n 24 --size 256 --colour-space linear_srgb \\
        --natural '{"components": {"grain": {"relative": {"probability": 0.5, "contrast": [0.01, 0.08]}}}}' --quiet
Score: the mean of the four means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its four means is more than 0.05 dB below the
incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Reported, not part of the rule: the G -> R and B -> R grain-transfer slopes of borrow_probe.py
(training/runs/dye_2026-11-26/). Kodak/McMaster are scored afterwards, for reporting only.
"""
import sys

sys.path.insert(0, ".")
from training.heldout_screen import run_rule  # noqa: E402

SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain"]
INCUMBENT = "out/train_demosaic_noise_free_stage3/best.pt"

if __name__ == "__main__":  # [--candidate PATH] for a dry run of this script
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_relgrain/best.pt", SETS,
                              "training/runs/relgrain_2026-11-26/screen_heldout.json",
                              "out/relgrain_screen_dryrun.json"))
