"""A call under torch.inference_mode, as a validation step makes, must not break the training steps after it (a
training-loop audit of 2026-12-01): caches and scratch buffers first made there were inference tensors, and every
later call outside it failed ('Inplace update to inference tensor outside InferenceMode', 'Inference tensors cannot
be saved for backward'). Run in a fresh process, so the caches are first filled under inference mode."""

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import torch, warnings
    warnings.simplefilter("ignore")
    from isettorch import scene
    from isettorch.camera import Camera
    from isettorch.isp import demosaic
    from isettorch.optics import DiffractionLimitedOptics

    s = scene.macbeth(patch_size=6, dtype=torch.float64)
    with torch.inference_mode():
        DiffractionLimitedOptics(f_number=4.0)(s)
        Camera.from_config("default")(s)
        demosaic(torch.rand(1, 1, 16, 16), "RGGB", method="learned_tiny")
    DiffractionLimitedOptics(f_number=4.0)(s)  # a scratch buffer made under inference mode failed here
    t = torch.tensor([0.01], dtype=torch.float64, requires_grad=True)
    Camera.from_config("default")(s, exposure_s=t).sum().backward()
    raw = torch.rand(1, 1, 16, 16, requires_grad=True)
    demosaic(raw, "RGGB", method="learned_tiny").sum().backward()  # the cached network's weights failed here
    assert t.grad is not None and raw.grad is not None
    print("ok")
""")


def test_an_inference_mode_call_leaves_later_training_calls_working():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
