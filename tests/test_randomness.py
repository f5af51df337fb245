"""Randomness (an audit of 2026-12-01): a sensor's random streams are distinct from every other seed's, a seed is
checked where it is taken, shuffled loaders give the same order for any number of workers in every epoch, and loading
a model or iterating a stream's loader leaves the global generator alone."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from isettorch.data.camera_pairs import CameraPairDataset, batch_loader, collate_pairs
from isettorch.data.natural import generate_natural
from isettorch.data.scenes import generate_scene
from isettorch.design import bound_patches, evaluate_design, load_design, make_design
from isettorch.isp.evaluation import noisy_mosaic
from isettorch.sensor import Sensor
from isettorch.sensor.noise import fixed_pattern_draws
from isettorch.sensor.noise_terms import NoiseTerms

H = 64


def _corr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(np.corrcoef(a.flatten().numpy(), b.flatten().numpy())[0, 1])


def test_a_sensors_temporal_noise_is_no_other_seeds_fixed_pattern():
    """Sensor(seed=0)'s default temporal generator was seeded 0 + 1, the DSNU map of Sensor(seed=1): its first read
    noise frame equalled that map (correlation 1.0). 4096 pixels: independent maps correlate within ~4 / 64."""
    dark = torch.zeros(1, 1, H, H, dtype=torch.float64)
    temporal = Sensor(rows=H, cols=H, cfa="RGGB", shot_noise="off", read_noise_v=1.0, seed=0)
    frame = temporal.capture(dark, exposure_s=0.01).data
    other = Sensor(rows=H, cols=H, cfa="RGGB", shot_noise="off", dsnu_sigma_v=1.0, seed=1)
    dsnu = other.fixed_pattern(H, H, dtype=torch.float64, device="cpu")["dsnu"]
    assert frame.std() > 0.2  # read noise is there (1 V, clipped to the 1 V swing)
    assert abs(_corr(frame, dsnu)) < 0.06
    # the dark-shading / hot-pixel patterns were seed + 7919's DSNU map
    shading = NoiseTerms(dark_shading_e_per_s=1.0, seed=3).patterns(H, H, dtype=torch.float64, device="cpu")["shading"]
    assert abs(_corr(shading, fixed_pattern_draws(H, H, 3 + 7919)["dsnu"])) < 0.06
    assert abs(_corr(shading, fixed_pattern_draws(H, H, 3)["dsnu"])) < 0.06


def test_sensor_seeds_span_torchs_seeds_and_no_more():
    """Sensor(seed=2**64 - 1) built, then its first capture failed with 'Overflow when unpacking long long' (seed + 1);
    2**64 was taken and failed the same way."""
    s = Sensor(rows=8, cols=8, cfa="RGGB", read_noise_v=1e-3, seed=2**64 - 1)
    raw = s.capture(torch.full((1, 1, 8, 8), 100.0, dtype=torch.float64), exposure_s=0.01)
    assert torch.isfinite(raw.data).all()
    with pytest.raises(ValueError, match=r"seed: expected an integer in \[0, 2\*\*64\)"):
        Sensor(rows=8, cols=8, seed=2**64)
    with pytest.raises(ValueError, match="seed: expected an integer"):
        Sensor(rows=8, cols=8, seed=-1)


@pytest.mark.parametrize("call", [
    lambda seed: generate_scene(0, seed, {"height": 16, "width": 16}),
    lambda seed: generate_natural(0, seed, {"size": 16}),
    lambda seed: noisy_mosaic(torch.full((1, 1, 4, 4), 0.5), 0.01, seed=seed),
    lambda seed: bound_patches(torch.arange(400.0, 701.0, 10.0), 4, 4, seed),
    lambda seed: make_design({"filters": ["learned", "W"], "mosaic_shape": [2, 2]}, seed=seed),
])
@pytest.mark.parametrize("seed", [-1, 2**64, 1.5, True, "3"])
def test_seeds_are_checked_where_they_are_taken(call, seed):
    """-1 drew what 2**64 - 1 draws and 2**64 what 0 draws; 1.5 and True were seed 1, "3" seed 3."""
    with pytest.raises((ValueError, TypeError), match="seed: expected an integer"):
        call(seed)


def test_evaluate_design_checks_its_seed(tmp_path):
    """evaluate_design(seed=2**64) ran as seed 0 and reported 18446744073709551616; 1.5 ran as 1."""
    photo = [("flat", np.full((24, 24, 3), 128, np.uint8))]
    for seed in (2**64, 1.5, -1):
        with pytest.raises(ValueError, match="seed: expected an integer"):
            evaluate_design("bayer_rgb", photo, seed=seed, crop=2)


def test_shuffled_batch_loader_order_is_the_same_for_any_workers_in_every_epoch():
    """With workers, batch_loader keeps them across epochs (persistent_workers): torch then draws no new base seed
    from the generator, and from the second epoch the sampler's permutation differed from num_workers=0's."""
    ds = CameraPairDataset(8, seed=2, scene={"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]},
                           targets=("camera_rgb",))

    def epochs(loader, n=3):
        return [[b["meta"]["index"].tolist() for b in loader] for _ in range(n)]

    ref = epochs(DataLoader(ds, batch_size=3, shuffle=True, generator=torch.Generator().manual_seed(1),
                            collate_fn=collate_pairs))
    assert ref[1] != ref[0]
    for workers in (0, 2):
        got = epochs(batch_loader(ds, 3, shuffle=True, generator=torch.Generator().manual_seed(1),
                                  num_workers=workers))
        assert got == ref, workers


def test_loading_models_and_stream_loaders_leave_the_global_generator_alone():
    """load_design(name) and the first learned demosaic built networks whose initial weights drew from the global
    generator before the file's replaced them; a stream's loader drew its workers' base seed from it on every
    iter(): a validation call moved a training run's own random numbers."""
    from isettorch.data import PairStream
    from isettorch.isp.learned import PRETRAINED, load_checkpoint

    torch.manual_seed(123)
    before = torch.get_rng_state()
    load_design("bayer_rgb")
    load_checkpoint(PRETRAINED["tiny"] if "tiny" in PRETRAINED else next(iter(PRETRAINED.values())))
    stream = PairStream(2, seed=0, scene={"height": 16, "width": 16}, targets=("camera_rgb",))
    next(iter(stream.loader(1)))
    assert torch.equal(torch.get_rng_state(), before)


def test_scene_datasets_take_a_samplers_tensor_index():
    """The new index check refused a 0-d tensor index, which the scene datasets took before (a sampler may give one);
    the datasets read their index as CameraPairDataset does (negative ones count from the end)."""
    from isettorch.data.natural import NaturalSceneDataset
    from isettorch.data.scenes import SyntheticSceneDataset

    ds = SyntheticSceneDataset(4, seed=1, config={"height": 16, "width": 16})
    assert torch.equal(ds[torch.tensor(2)].photons, ds[2].photons)
    assert torch.equal(ds[-1].photons, ds[3].photons)
    nat = NaturalSceneDataset(4, seed=1, config={"size": 16})
    assert torch.equal(nat[torch.tensor(2)]["maps"], nat[2]["maps"])
    with pytest.raises(TypeError, match="index: expected an integer"):
        nat[1.5]
    assert torch.equal(generate_scene(torch.tensor(3), 1, {"height": 16, "width": 16}).photons,
                       generate_scene(3, 1, {"height": 16, "width": 16}).photons)


def test_more_seed_entry_points(tmp_path, capsys):
    """A photo dataset's seed -1 gave the items of 2^64 - 1, dead_leaves(seed=2**64) overflowed unnamed, and the demo
    command's --seed -1 failed in torch."""
    from isettorch.cli import main
    from isettorch.data.photos import PhotoSceneDataset
    from isettorch.io.images import write_image
    from isettorch.scene.dead_leaves import dead_leaves

    write_image(tmp_path / "a.png", torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(0)))
    with pytest.raises(ValueError, match=r"seed: expected an integer in \[0, 2\*\*64\)"):
        PhotoSceneDataset(tmp_path, 16, seed=-1)
    with pytest.raises(ValueError, match=r"seed: expected an integer in \[0, 2\*\*64\)"):
        dead_leaves(16, seed=2**64)
    assert main(["demo", "--seed", "-1", "--out", str(tmp_path / "demo")]) == 2
    assert "--seed: expected an integer in [0, 2**64)" in capsys.readouterr().err


def test_stock_transport_loader_epochs_without_a_generator():
    """EpochLoader on the stock transport (no shared-memory slots) and without a generator: the global generator
    gives the same order for 0 and 2 workers in every epoch, as stock non-persistent loaders do."""
    ds = CameraPairDataset(6, seed=3, scene={"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]},
                           targets=("camera_rgb",))
    orders = []
    for workers in (0, 2):
        torch.manual_seed(11)
        loader = batch_loader(ds, 2, shuffle=True, num_workers=workers, shm_slots=False)
        orders.append([[b["meta"]["index"].tolist() for b in loader] for _ in range(3)])
    assert orders[0] == orders[1] and orders[0][0] != orders[0][1]
