"""Shipping screen for the fourth distillation round (configs/train/demosaic_noise_free_distill4.yaml: the dihedral
teacher again, 4800 s, a fresh bank), written on 2026-11-27 at about 05:15 UTC, before the run was started (so before
any of its checkpoints existed). The same rule and sets as the first three rounds' screens
(training/runs/distill_2026-11-27/screen_rule.py).

Incumbent: the shipped network, distill-3 (out/train_demosaic_noise_free_distill3/best.pt: the asset of d1b30b8),
one pass.
Candidate: out/train_demosaic_noise_free_distill4/best.pt, one pass (``--candidate`` overrides it for a dry run).
Sets (24 x 256 px each, crop 10, RGGB): out/heldout_v5, out/heldout_v5_stress, out/heldout_stress and
out/heldout_v5_relgrain, rewritten in this checkout by training/make_heldout.py --n 24 --size 256 --colour-space
linear_srgb with, in turn: no option; --channel-gains 1 0.15 0.15 --grain-std 0.005; the same with --natural
'{"components": {"colour_correlation": {"chromatic_radius_px": 16.0, "chromatic_detail_probability": 0.25},
"grain": {"enabled": false}}}' (generator v4); --natural '{"components": {"grain": {"relative": {"probability": 0.5,
"contrast": [0.01, 0.08]}}}}'. Checked before the run: distill-3 scores on them within 4e-4 dB per image of its row in
training/runs/distill3_2026-11-27/screen_heldout.json (means 39.697 / 36.941 / 37.242 / 36.285).
Score: the mean of the four means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its four means is more than 0.05 dB below the
incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Kodak/McMaster and the scikit-image photos are scored afterwards, for reporting only.
"""
import sys

sys.path.insert(0, ".")
from training.heldout_screen import run_rule  # noqa: E402

SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain"]
INCUMBENT = "out/train_demosaic_noise_free_distill3/best.pt"

if __name__ == "__main__":  # [--candidate PATH] for a dry run of this script
    raise SystemExit(run_rule(INCUMBENT, "out/train_demosaic_noise_free_distill4/best.pt", SETS,
                              "training/runs/distill4_2026-11-27/screen_heldout.json",
                              "out/distill4_screen_dryrun.json"))
