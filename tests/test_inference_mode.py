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


SCENE_GRADIENT = textwrap.dedent("""
    import torch, warnings
    warnings.simplefilter("ignore")
    from isettorch import metrics, scene
    from isettorch.optics import DiffractionLimitedOptics

    s = scene.macbeth(patch_size=6, dtype=torch.float64)
    with torch.inference_mode():
        DiffractionLimitedOptics(f_number=4.0)(s)
        metrics.xyz_to_srgb(torch.rand(1, 3, 4, 4, dtype=torch.float64))
    photons = s.photons.clone().requires_grad_(True)  # the cached OTF was an inference tensor here
    DiffractionLimitedOptics(f_number=4.0)(scene.Scene(photons, s.wavelengths_nm)).photons.sum().backward()
    x = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    metrics.xyz_to_srgb(x).sum().backward()  # (the cached sRGB matrix likewise)
    assert photons.grad is not None and x.grad is not None
    print("ok")
""")


def test_cached_otfs_and_matrices_made_under_inference_mode_take_gradients():
    """The re-read of the first fix: the optics' OTF caches and the sRGB matrices cached under inference mode still
    refused a later gradient to the scene."""
    out = subprocess.run([sys.executable, "-c", SCENE_GRADIENT], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


LIFT = textwrap.dedent("""
    import torch
    from isettorch.data import photos, spectra
    from isettorch.data.scenes import _luminance_weights

    wl = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    with torch.inference_mode():
        spectra.srgb_basis_spectra(wl)
        _luminance_weights(wl)  # (the natural scenes' luminance weights, likewise)
        photos.lift_srgb(torch.full((3, 4, 4), 0.5, dtype=torch.float64))
    gain = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    lifted = photos.lift_srgb(torch.full((3, 4, 4), 0.5, dtype=torch.float64))
    (lifted["reflectance"] * gain).sum().backward()  # the basis cached under inference mode failed here
    (_luminance_weights(wl) * gain).sum().backward()
    basis = spectra.srgb_basis_spectra(wl)
    first = basis.clone()
    basis.mul_(0.0)  # the caller's own copy: the next call's basis is unchanged
    assert torch.equal(spectra.srgb_basis_spectra(wl), first) and float(first.sum()) > 0
    want = float(first.sum() + _luminance_weights(wl).sum())
    assert abs(float(gain.grad) - want) <= 1e-12 * want
    v = _luminance_weights(wl)
    v_first = v.clone()
    v.mul_(0.0)  # (the luminance weights, likewise)
    assert torch.equal(_luminance_weights(wl), v_first) and float(v_first.sum()) > 0
    drawn = spectra.random_reflectances(5, wl, torch.Generator().manual_seed(3), model="pca")
    for x in spectra.reflectance_basis(wl, 8, dtype=torch.float64):
        x.mul_(0.0)  # (the public PCA model, likewise: the seeded PCA reflectances are drawn from the cached one)
    mean, basis, _ = spectra.reflectance_basis(wl, 8, dtype=torch.float64)
    assert float(mean.sum()) > 0 and float(basis.abs().sum()) > 0
    again = spectra.random_reflectances(5, wl, torch.Generator().manual_seed(3), model="pca")
    assert torch.equal(again, drawn)
    print("ok")
""")


def test_the_photo_lifts_basis_made_under_inference_mode_takes_gradients():
    """An audit of the data-path caches (2026-12-01): the sRGB basis of the photo lifter was an lru_cache of a
    tensor, handed to the caller: first made under inference mode it refused later gradients, and an in-place edit of
    a returned basis changed every later lift."""
    out = subprocess.run([sys.executable, "-c", LIFT], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


DRAWS = textwrap.dedent("""
    import torch
    from isettorch.data.config import randint_scalar, uniform01

    g = torch.Generator().manual_seed(5)
    with torch.inference_mode():
        uniform01(g), randint_scalar(0, 10, g)  # the per-thread draw buffers are first made here
    g = torch.Generator().manual_seed(7)
    u, i = uniform01(g), randint_scalar(0, 10, g)  # an inference buffer failed here
    ref = torch.Generator().manual_seed(7)
    assert u == float(torch.rand((), generator=ref, dtype=torch.float64))
    assert i == int(torch.randint(0, 10, (), generator=ref))
    print("ok")
""")


def test_scalar_draws_first_made_under_inference_mode_still_draw_outside_it():
    """A re-read of the inference-mode fixes (2026-12-01): the scene generator's scalar draws reuse a per-thread 0-d
    tensor; first made under inference mode, every later draw outside it failed."""
    out = subprocess.run([sys.executable, "-c", DRAWS], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
