"""Synthetic data: random physical spectra, scene layouts, scene and camera-pair datasets, dataset writers."""

from .config import CAMERA_DEFAULTS, SCENE_DEFAULTS, SYNTH_DEFAULTS, load_config, merge_config, seed_for, tune_allocator
from .scenes import SyntheticSceneDataset, collate_scenes, generate_scene
from .stream import PairStream
from .stream_workers import stream_loader

__all__ = ["PairStream", "SyntheticSceneDataset", "collate_scenes", "generate_scene", "load_config", "merge_config",
           "seed_for", "stream_loader", "tune_allocator",
           "SCENE_DEFAULTS", "CAMERA_DEFAULTS", "SYNTH_DEFAULTS"]
