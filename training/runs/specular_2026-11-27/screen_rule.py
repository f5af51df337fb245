"""Shipping screen for the specular run (configs/train/demosaic_noise_free_specular.yaml: distill-4 continued for 3600 s
on generator version 5 with components.specular on in every scene, own targets, a fresh bank), written on 2026-11-27
at about 07:23 UTC (commit 0dac932), before the run was started (so before any of its checkpoints existed). The rule
of the earlier screens (training/heldout_screen.py), on the four sets of the distillation rounds plus one set drawn
with the candidate generator's option, as the relative-grain screen did for its run.

Incumbent: the shipped network, distill-4 (out/train_demosaic_noise_free_distill4/best.pt: the asset of 7ce47d7),
one pass.
Candidate: out/train_demosaic_noise_free_specular/best.pt, one pass (``--candidate`` overrides it for a dry run).
Sets (24 x 256 px each, crop 10, RGGB): out/heldout_v5, out/heldout_v5_stress, out/heldout_stress,
out/heldout_v5_relgrain (the commands of training/runs/distill4_2026-11-27/screen_rule.py) and out/heldout_spec1:
training/make_heldout.py --n 24 --size 256 --colour-space linear_srgb --natural '{"components": {"specular":
{"probability": 1.0}}}'. The fifth set is drawn from the candidate's training distribution (other seeds), so it
favours the candidate; the 0.05 dB guard on each of the other four sets is what keeps the rule honest.
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
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_specular/best.pt", SETS,
                              "training/runs/specular_2026-11-27/screen_heldout.json",
                              "out/specular_screen_dryrun.json"))
