"""Dtypes end to end (an audit of 2026-12-01 that ran every entry point in float32 and float64, under either default
dtype, with a dispatch tracer of downcasts): a float64 camera holds float64 constants however it was built, mixed
and half precisions are promoted or refused by name, never computed wrong."""

import numpy as np
import pytest
import torch

from isettorch import metrics
from isettorch.camera import Camera
from isettorch.io.images import read_image, write_image
from isettorch.isp import ImageProcessor
from isettorch.metrics.difference import macbeth_reference_xyz
from isettorch.scene import macbeth, monochromatic


def _built_under_float64(make):
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        return make()
    finally:
        torch.set_default_dtype(before)


def test_a_camera_moved_to_float64_holds_float64_constants():
    """The display matrices and the processor's white were rounded to float32 when built and .to(float64) upcast
    the roundings: the final image was 1.8e-7 (relative) off the camera built in float64."""
    scene = macbeth(patch_size=8, dtype=torch.float64)
    moved = Camera.from_config("default").to(torch.float64)
    built = _built_under_float64(lambda: Camera.from_config("default"))
    for cam in (moved, built):
        cam.noise = False
    a, b = moved(scene), built(scene)
    assert a.dtype == b.dtype == torch.float64
    assert float((a - b).abs().max()) <= 1e-12 * float(b.abs().max())
    # and back: a float64-built processor moved to float32 holds the float32 roundings of the float64 values
    p64 = _built_under_float64(ImageProcessor)
    p32 = ImageProcessor().float()
    assert torch.equal(p64.float().xyz_to_display.matrix, p32.xyz_to_display.matrix)
    assert torch.equal(p64.white_xyz.float(), p32.white_xyz)


def test_colour_differences_of_a_half_and_a_wider_colour():
    """A float16 colour beside a float64 one was computed in float16: dE2000 NaN, dE94 inf once |a| or |b| > ~181."""
    lab1 = torch.tensor([29.0, 269.4, -104.9], dtype=torch.float64).reshape(1, 3, 1, 1)
    lab2 = torch.tensor([28.1, 272.8, -106.0], dtype=torch.float64).reshape(1, 3, 1, 1)
    half = lab2.half()
    for fn in (metrics.delta_e_2000, metrics.delta_e_94, metrics.delta_e_76):
        got = fn(lab1, half)
        assert got.dtype == torch.float64
        torch.testing.assert_close(got, fn(lab1, half.double()), rtol=1e-12, atol=0)


def test_read_image_refuses_what_its_dtype_cannot_hold(tmp_path):
    """An EXR of 1e5 read as float16 came back inf; a PNG read as uint8 came back all zeros (values in [0, 1])."""
    exr = tmp_path / "bright.exr"
    write_image(exr, torch.full((1, 3, 4, 4), 1e5), bits=32)
    with pytest.raises(ValueError, match=r"dtype: .* beyond torch.float16's range"):
        read_image(exr, dtype=torch.float16)
    assert float(read_image(exr, dtype=torch.float32).max()) == 1e5
    png = tmp_path / "photo.png"
    write_image(png, torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(0)))
    with pytest.raises(TypeError, match="dtype: expected a floating torch.dtype"):
        read_image(png, dtype=torch.uint8)
    assert read_image(png, dtype=torch.float16).dtype == torch.float16  # [0, 1] fits float16


@pytest.mark.parametrize("make", [lambda dt: macbeth(dtype=dt), lambda dt: monochromatic(dtype=dt),
                                  lambda dt: monochromatic(wavelengths=torch.arange(400.0, 701.0, 10.0).to(dt))])
@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_scenes_are_refused_by_name(make, dtype):
    """float16 radiance (~1e16) overflowed: 'spectra: expected finite values, found 744 NaN/Inf entries'; bfloat16
    rounded 550 nm to 552: 'wavelength_nm: expected one of the grid's samples [552.0], got 550.0'."""
    with pytest.raises(ValueError, match=r"(dtype|wavelengths \(the scene's dtype\)): expected torch.float32 or "
                                         r"torch.float64, got torch\.b?float16"):
        make(dtype)


def test_scielab_and_colour_accuracy_take_half_and_mixed_precision():
    """scielab on half images raised in linalg.inv and cast xyz2 to xyz1's dtype; color_accuracy's median raised in
    torch.quantile for half input."""
    g = torch.Generator().manual_seed(1)
    x1 = torch.rand(1, 3, 24, 24, generator=g, dtype=torch.float64) * 0.9
    x2 = (x1 + 0.02 * torch.rand(1, 3, 24, 24, generator=g, dtype=torch.float64)).clamp(0, 1)
    ref = metrics.scielab(x1, x2, "D65", 23.0)
    mixed = metrics.scielab(x1.float(), x2, "D65", 23.0)  # promoted to float64 (x2 was cast to float32)
    assert mixed.dtype == torch.float64
    torch.testing.assert_close(mixed, metrics.scielab(x1.float().double(), x2, "D65", 23.0), rtol=1e-12, atol=1e-12)
    half = metrics.scielab(x1.half(), x2.half(), "D65", 23.0)
    assert half.dtype == torch.float16 and torch.isfinite(half).all()
    assert float((half.double() - ref).abs().mean()) < 0.05 * float(ref.mean())
    chart, _ = macbeth_reference_xyz("D65")
    rendered = chart * torch.tensor([1.02, 1.0, 0.98], dtype=chart.dtype)
    acc = metrics.color_accuracy(rendered.half(), chart.half(), white="D65")
    acc64 = metrics.color_accuracy(rendered, chart, white="D65")
    assert np.isclose(float(acc.median), float(acc64.median), rtol=2e-2)


def test_moving_keeps_a_constant_that_was_replaced():
    """The float64 constants are cast again only while a buffer still holds its constant: an assigned matrix or a
    checkpoint's white survives .to() / .double() (the first fix brought the constructor's values back)."""
    p = ImageProcessor()
    m = 2 * torch.eye(3)
    p.xyz_to_display.matrix = m.clone()
    p.to("cpu")
    assert torch.equal(p.xyz_to_display.matrix, m)
    p.double()
    assert torch.equal(p.xyz_to_display.matrix, m.double())
    q = ImageProcessor()
    state = q.state_dict()
    state["white_xyz"] = torch.tensor([0.9, 1.0, 1.1])
    q.load_state_dict(state)
    q.double()
    assert torch.equal(q.white_xyz, torch.tensor([0.9, 1.0, 1.1]).double())


def test_half_colour_accuracy_is_returned_in_half():
    chart, _ = macbeth_reference_xyz("D65")
    acc = metrics.color_accuracy(chart.half() * 1.01, chart.half(), white="D65")
    assert acc.delta_e.dtype == acc.median.dtype == torch.float16


def test_the_physics_keeps_its_precision_under_autocast():
    """Under CPU bfloat16 autocast a camera failed ('electron_rate: expected torch.float32 or torch.float64, got
    torch.bfloat16', from the sensor's sampling product) and a stream's OTF product moved its float32 batch by
    3.5e-4 unsaid; the physics now runs in its inputs' precision, a network after it still autocasts."""
    from isettorch.data import PairStream

    scene = macbeth(patch_size=6)
    cam = Camera.from_config("default")
    cam.noise = False
    ref = cam(scene)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = cam(scene)
    assert got.dtype == torch.float32 and torch.equal(got, ref)
    stream = PairStream(2, seed=0, scene={"height": 32, "width": 32}, camera=Camera.from_config("default"),
                        grad=True, targets=("camera_rgb",))
    ref = stream.batch(0)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = stream.batch(0)
    for key in ("raw", "camera_rgb"):
        assert got[key].dtype == torch.float32 and torch.equal(got[key].detach(), ref[key].detach()), key


def test_a_processor_moves_through_the_meta_device():
    """ExactConstants read each buffer back on the host to see whether it still held its constant: a processor moved
    to 'meta' (no values) raised 'Cannot copy out of meta tensor' in to_empty()."""
    p = ImageProcessor().to("meta")
    p.to_empty(device="cpu")
    assert p.white_xyz.device.type == "cpu"
