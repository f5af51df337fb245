"""Paths that built a tensor on the CPU and met the caller's device (a device audit of 2026-12-01, with a tracer that
flags CPU tensors of one or more dimensions meeting CUDA ones): each runs on ``device`` (CUDA cases skip without a
GPU) and is compared with the same computation on the CPU."""

import torch

from isettorch import metrics
from isettorch.data import PairStream
from isettorch.optics import WavefrontOptics
from isettorch.optics.factory import build_optics
from isettorch.scene import slanted_edge
from isettorch.scene.macbeth import macbeth


def _on(t: torch.Tensor, device: torch.device) -> torch.Tensor:
    assert t.device.type == device.type
    assert torch.isfinite(t).all()
    return t.cpu()


def test_wavefront_defocus_on_the_device(device):
    """The defocus term was added through a CPU one-hot vector (the README's defocus_diopters=2.0 example)."""
    def psf(dev):
        o = WavefrontOptics(zernike_um=torch.zeros(15, dtype=torch.float64), f_number=4.0, focal_length_m=3.86e-3,
                            defocus_diopters=2.0).to(dev)
        return o(macbeth(patch_size=4, device=dev, dtype=torch.float64)).photons

    ref = psf(torch.device("cpu"))
    torch.testing.assert_close(_on(psf(device), device), ref, rtol=1e-6, atol=1e-9 * float(ref.max()))


def test_lens_full_psf_path_on_the_device(device):
    """Without an eigen-PSF basis (components None) the PSF table and its polar interpolation stayed on the CPU."""
    def oi(dev):
        o = build_optics({"type": "lens", "lens": "cooke_triplet", "components": None, "field_samples": 5,
                          "azimuth_samples": 8}).to(dev)
        return o(macbeth(patch_size=4, device=dev, dtype=torch.float64)).photons

    got = _on(oi(device), device)
    if device.type != "cpu":  # (on the CPU, the run itself is the check: 4 s)
        ref = oi(torch.device("cpu"))
        torch.testing.assert_close(got, ref, rtol=1e-6, atol=1e-9 * float(ref.max()))


def test_stream_with_configured_optics_on_the_device(device):
    """A camera.optics mapping (wavefront, zernike, a PSF file) was built on the CPU and never moved to the stream's
    device (the drawn diffraction optics and the sensor were)."""
    for optics in ({"type": "wavefront", "zernike_um": [0, 0, 0, 0, 0.2]},
                   {"type": "wavefront", "zernike_um": [0, 0, 0, 0, 0, 0.1], "defocus_diopters": 1.0}):
        b = PairStream(2, seed=0, device=device, scene={"height": 32, "width": 32}, camera={"optics": optics},
                       targets=("camera_rgb",)).batch(0)
        assert _on(b["camera_rgb"], device).amax() > 0
        _on(b["raw"], device)


def test_esfr_on_the_device(device):
    """The edge search and line fit built CPU grids that met a CUDA image."""
    img = slanted_edge(size=96, dtype=torch.float64).photons[0].sum(0)
    ref = metrics.esfr(img)
    got = metrics.esfr(img.to(device))
    assert got.mtf50.device.type == device.type
    torch.testing.assert_close(got.mtf50.cpu(), ref.mtf50, rtol=1e-9, atol=0)
