"""The config keys :mod:`training.train_demosaic` reads, checked before a run starts: a misspelt key
(``optim.lrr``, ``data.batchsize``) ran silently with its default, ``optim.loss: l3`` trained with L2, and
``checkpoint_every: 0`` failed later with a division by zero. The ``net`` section is :class:`DemosaicNet`'s
arguments (it names an unknown one); ``data.scene``, ``data.camera`` and ``data.natural`` are the library's
configs, checked where they are used."""

from __future__ import annotations

from training.common import check_keys, check_number

#: every key of each section the trainer or its parts (demosaic_data, demosaic_pairs, demosaic_noise,
#: demosaic_checkpoints) read
SECTION_KEYS = {
    "data": {"bank", "bank_dir", "bank_workers", "batch", "camera", "camera_config", "colour_space", "device",
             "disable", "domain", "encoded_fraction", "hard_mining", "natural", "patch", "pool", "refresh", "scene",
             "scene_config", "scene_seed", "scene_size", "sensitivities", "source", "stream_chunk"},
    "noise": {"bits", "clean_fraction", "dark_e", "dsnu_e", "enabled", "full_well_e", "gain_max", "gain_min",
              "gaussian_fraction", "prnu_percent", "read_noise_e", "sigma_max", "sigma_min"},
    "optim": {"clip_grad_factor", "loss", "lr", "lr_min", "precision", "steps", "time_budget_s", "warmup"},
    "val": {"every", "images", "size"},
    "eval": {"benchmarks", "every"},
    "distill": {"self_ensemble", "shipped", "teacher", "weight"},
    "net": None,
}
TOP_KEYS = {"checkpoint_every", "expand", "init", "out", "seed", "threads", *SECTION_KEYS}
LOSSES = ("l1", "l2")


def _positive(value, name: str, integer: bool = False) -> None:
    check_number(value, name, integer=integer, above=0)


def check_config(cfg: dict) -> dict:
    """``cfg`` if every key is one the trainer reads and the values it divides or counts by are in range, else a
    ValueError naming the key (``config.optim.lrr: unknown key; expected one of [...]``)."""
    check_keys(cfg, TOP_KEYS, SECTION_KEYS, nullable=("distill",))  # (null distill: none; null noise crashed)
    optim = cfg.get("optim") or {}
    if "steps" not in optim or "lr" not in optim:
        raise ValueError(f"config.optim: expected steps and lr, got {sorted(optim)}")
    _positive(optim["steps"], "optim.steps", integer=True)
    _positive(optim["lr"], "optim.lr")
    if optim.get("loss", "l2") not in LOSSES:
        raise ValueError(f"config.optim.loss: expected one of {LOSSES}, got {optim['loss']!r}")
    data, val, noise = cfg.get("data") or {}, cfg.get("val") or {}, cfg.get("noise") or {}
    for name, value in (("checkpoint_every", cfg.get("checkpoint_every", 100)),
                        ("data.batch", data.get("batch", 16)),
                        ("val.every", val.get("every", 200)),
                        ("val.images", val.get("images", 32)),
                        # (read by int(): 'abc' failed unnamed, 0 pool in torch.randint, -8 was blamed on data.patch)
                        ("data.patch", data.get("patch", 80)),
                        ("data.pool", data.get("pool", 64)),
                        ("val.size", val.get("size", 128))):
        _positive(value, name, integer=True)
    for name, value in (("optim.warmup", optim.get("warmup", 50)), ("data.refresh", data.get("refresh", 2)),
                        ("seed", cfg.get("seed", 0))):
        if not (_is_int(value) and value >= 0):  # (-5 and -1 ran silently)
            raise ValueError(f"config.{name}: expected an integer >= 0, got {value!r}")
    _positive(optim.get("lr_min", 1e-5), "optim.lr_min")
    fraction = data.get("encoded_fraction", 0.8)
    if not (isinstance(fraction, (int, float)) and not isinstance(fraction, bool) and 0 <= fraction <= 1):
        raise ValueError(f"config.data.encoded_fraction: expected a fraction in [0, 1], got {fraction!r}")
    # validation scores crop 4 pixels a side of whole scenes of an even size (8 failed after val.every steps in
    # the crop check; 33 was blamed on data.patch)
    size = val.get("size", 128)
    if not (_is_int(size) and size >= 10 and size % 2 == 0):
        raise ValueError(f"config.val.size: expected an even number of pixels >= 10 (validation crops 4 a side), got "
                         f"{size!r}")
    if noise.get("enabled", False):
        for key in ("gain_min", "gain_max"):  # (gain_min 0: a ZeroDivisionError)
            if key in noise:
                _positive(noise[key], f"noise.{key}")
        # (a gaussian_fraction of 2 failed in a tensor expand before the batch's own check of the sum)
        fractions = [noise.get(k, 0.0) for k in ("clean_fraction", "gaussian_fraction")]
        for key, value in zip(("clean_fraction", "gaussian_fraction"), fractions):
            check_number(value, f"noise.{key}", minimum=0)
        if sum(fractions) > 1:
            raise ValueError(f"config.noise.clean_fraction, config.noise.gaussian_fraction: expected fractions with a "
                             f"sum in [0, 1], got {fractions[0]!r}, {fractions[1]!r}")
    return cfg


def _is_int(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, int)
