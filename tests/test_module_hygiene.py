"""PyTorch module hygiene (an audit of 2026-12-01): checkpoints load into freshly built modules and resume as the
module they came from, inference mode, dtype moves of everything a module runs, and caches that see new inputs."""

import gc
import io
import math
import weakref

import torch

from isettorch.camera import Camera
from isettorch.optics import DiffractionLimitedOptics
from isettorch.optics.optical_image import OpticalImage
from isettorch.scene import checkerboard
from isettorch.sensor import Sensor
from isettorch.sensor.microlens import PixelOptics

W = torch.arange(450.0, 651.0, 50.0, dtype=torch.float64)


def _scene():
    # (the grid made here: under inference mode an inference tensor)
    return checkerboard(size=32, square_size=4, wavelengths=W.clone(), dtype=torch.float64)


def _saved(module):
    buf = io.BytesIO()
    torch.save(module.state_dict(), buf)
    buf.seek(0)
    return torch.load(buf, weights_only=True)


def _noisy_camera():
    return Camera(DiffractionLimitedOptics(), Sensor(rows=16, cols=16, pixel_size_m=2e-6, dsnu_sigma_v=1e-3,
                                                     prnu_sigma_percent=1.0, seed=3), noise=True)


def test_a_camera_that_rendered_fixed_pattern_noise_loads_into_a_new_one():
    """The fixed-pattern maps are the sensor's seed's: not in the state_dict, so a camera that had rendered could be
    loaded strictly into a new one (it failed: 'Unexpected key(s) sensor.fpn_dsnu'); the new one draws the same."""
    cam = _noisy_camera()
    ref = cam.sensor(cam.optics(_scene()), generator=torch.Generator().manual_seed(0)).data
    state = _saved(cam)
    assert not any("fpn" in k for k in state)
    fresh = _noisy_camera()
    fresh.load_state_dict(state)
    torch.testing.assert_close(fresh.sensor(fresh.optics(_scene()), generator=torch.Generator().manual_seed(0)).data,
                               ref, rtol=0, atol=0)
    # a checkpoint saved while the maps were saved loads too (they are drawn again from the seed)
    legacy = dict(state, **{f"sensor.{k}": torch.zeros(16, 16, dtype=torch.float64)
                            for k in ("fpn_dsnu", "fpn_prnu", "fpn_column")})
    again = _noisy_camera()
    again.load_state_dict(legacy)
    torch.testing.assert_close(again.sensor(again.optics(_scene()), generator=torch.Generator().manual_seed(0)).data,
                               ref, rtol=0, atol=0)


def test_a_scene_built_under_inference_mode_renders():
    """Caches read tensors' version counters, which a tensor made under torch.inference_mode has not (it raised)."""
    def make():
        return Camera(DiffractionLimitedOptics(f_number=4.0), Sensor(rows=16, cols=16, pixel_size_m=2e-6,
                                                                     exposure_s=1e-3), noise=False)

    cam = make()
    ref = cam(_scene())
    with torch.inference_mode():
        inside = cam(_scene())
        again = cam(_scene())
        fresh = make()(_scene())
    assert torch.equal(inside, ref) and torch.equal(again, ref) and torch.equal(fresh, ref)


def test_the_joint_networks_gate_expert_follows_dtype_moves():
    """load_pretrained('joint_denoise') keeps its low-noise expert in a dict: .double() left it float32 and
    demosaic_learned raised a dtype error."""
    from isettorch.isp.learned import demosaic_learned, load_pretrained

    net = load_pretrained("joint_denoise").double()
    assert next(net.level_gate["expert"].parameters()).dtype == torch.float64
    raw = torch.rand(1, 1, 32, 32, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.5 + 0.25
    noise = torch.tensor([[1e-4, 1e-6]], dtype=torch.float64)
    out = demosaic_learned(raw, model=net, noise=noise)
    ref = demosaic_learned(raw.float(), model=load_pretrained("joint_denoise"), noise=noise.float())
    assert out.dtype == torch.float64
    torch.testing.assert_close(out.float(), ref, rtol=0, atol=2e-5)
    # the shipped copy stays float32
    assert next(load_pretrained("joint_denoise").level_gate["expert"].parameters()).dtype == torch.float32


def _oi(table):
    return OpticalImage(torch.ones(1, 1, 8, 8, dtype=torch.float64), torch.tensor([550.0], dtype=torch.float64),
                        sample_spacing_m=2e-6, f_number=4.0, focal_length_m=4e-3, image_distance_m=4e-3,
                        metadata={"chief_ray_angle": table})


def _table(scale):
    return {"image_height_m": torch.linspace(0, 1.2e-5, 5, dtype=torch.float64),
            "cra_deg": torch.linspace(0, 1, 5, dtype=torch.float64) * scale}


class _Table(dict):
    """A chief-ray table that can be watched with a weak reference."""


def test_pixel_optics_memo_never_serves_a_freed_tables_map():
    """The etendue memo was keyed on the id of the optics' chief-ray table without holding it: a new table at a
    freed one's address (a lens swapped on the sensor) got the old map, up to 1.0 off. The entry now holds it, so
    its address cannot be reused while the entry lives."""
    po = PixelOptics("centred")
    first = _Table(_table(2.0))
    po.etendue_map(_oi(first), 8, 8, 2e-6)
    watch = weakref.ref(first)
    del first
    gc.collect()
    assert watch() is not None
    t = _Table(_table(40.0))
    assert torch.equal(po.etendue_map(_oi(t), 8, 8, 2e-6), PixelOptics("centred").etendue_map(_oi(t), 8, 8, 2e-6))


def test_lens_camera_equation_is_the_lenss_own():
    """LensOptics' f_number buffer reports the traced lens's; an edit changed the camera equation until the first
    render cached it (and never the PSFs). The lens's own is used throughout."""
    from isettorch.optics.lens.optics import LensOptics
    from isettorch.scene.scene import Scene

    def make():
        return LensOptics("cooke_triplet", field_samples=3, azimuth_samples=4, components=4, distortion_samples=6,
                          pupil_samples=16, max_pupil_samples=32)

    o = make()
    half = math.degrees(math.atan(math.tan(math.radians(o.analysis.max_field_deg)) / math.sqrt(2)))
    s = Scene(torch.ones(1, 3, 24, 24, dtype=torch.float64), torch.tensor([450.0, 550.0, 650.0],
                                                                          dtype=torch.float64), hfov_deg=1.44 * half)
    edited = make()
    with torch.no_grad():
        edited.f_number.mul_(1.5)
    assert torch.equal(edited(s).photons, o(s).photons)
