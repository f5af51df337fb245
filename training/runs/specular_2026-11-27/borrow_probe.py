"""The dye run's grain-transfer probe (training/runs/dye_2026-11-26/borrow_probe.py: the least-squares slope of each
channel's error on another channel's grain at that channel's sites, 0 = nothing transferred) for the shipped
distill-4 and the specular and specmix networks, on the same 24 held-out v5 stress scenes; out/heldout_v5_sat is
training/make_heldout.py --n 24 --size 256 --colour-space linear_srgb --channel-gains 1 0.15 0.15. Diagnostic of the
stress-set loss, after the screens' decisions; no test set is read."""
import sys

sys.path.insert(0, ".")
sys.path.insert(0, "training/runs/dye_2026-11-26")
from borrow_probe import probe  # noqa: E402

if __name__ == "__main__":
    probe({k: f"out/train_demosaic_noise_free_{k}/best.pt" for k in ("distill4", "specular", "specmix")},
          "training/runs/specular_2026-11-27/borrow_probe.json")
