"""Shipping screen for the fifth distillation round (configs/train/demosaic_noise_free_distill5.yaml: the shipped
weight interpolation continued towards its own dihedral ensemble, 4800 s, a fresh bank with the specular sheen in half
the scenes), written on 2026-11-27 at about 10:10 UTC, before the run was started (so before any of its checkpoints
existed). The same rule and five sets as the specular and interpolation screens
(training/runs/wise_specular_2026-11-27/wise_rule.py).

Incumbent: the shipped network, 0.4 distill-4 + 0.6 specular (out/wise_specular/best.pt: the asset of 628fcc0), one
pass.
Candidate: out/train_demosaic_noise_free_distill5/best.pt, one pass (``--candidate`` overrides it for a dry run).
Sets (24 x 256 px each, crop 10, RGGB): out/heldout_v5, out/heldout_v5_stress, out/heldout_stress,
out/heldout_v5_relgrain, out/heldout_spec1 (commands in training/runs/specular_2026-11-27/screen_rule.py).
Score: the mean of the five means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its five means is more than 0.05 dB below the
incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Kodak/McMaster and the scikit-image photos are scored afterwards, for reporting only.
"""
import sys

sys.path.insert(0, ".")
from training.heldout_screen import run_rule  # noqa: E402

SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain",
        "out/heldout_spec1"]
INCUMBENT = "out/wise_specular/best.pt"

if __name__ == "__main__":  # [--candidate PATH] for a dry run of this script
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_distill5/best.pt", SETS,
                              "training/runs/distill5_2026-11-27/screen_heldout.json",
                              "out/distill5_screen_dryrun.json"))
