"""Shipping screen for the specmix run (configs/train/demosaic_noise_free_specmix.yaml: the specular run continued for
1800 s with the sheen in half the scenes, a fresh bank), written on 2026-11-27 at about 08:33 UTC (commit c631ce8),
before the run was started (so before any of its checkpoints existed). The same rule, incumbent and five sets as the
specular run's screen (training/runs/specular_2026-11-27/screen_rule.py), unchanged although that screen rejected a
network that then scored higher on every photograph set (its README): changing the rule after seeing Kodak would be
selecting on Kodak.

Incumbent: the shipped network, distill-4 (out/train_demosaic_noise_free_distill4/best.pt: the asset of 7ce47d7),
one pass.
Candidate: out/train_demosaic_noise_free_specmix/best.pt, one pass (``--candidate`` overrides it for a dry run).
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
INCUMBENT = "out/train_demosaic_noise_free_distill4/best.pt"

if __name__ == "__main__":  # [--candidate PATH] for a dry run of this script
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_specmix/best.pt", SETS,
                              "training/runs/specmix_2026-11-27/screen_heldout.json",
                              "out/specmix_screen_dryrun.json"))
