"""Demosaic benchmark scoring (the convention of shared/data/README.md): ground truth = 8-bit image / 255 taken as
linear values; Bayer mosaic (noise-free unless asked); output clipped to [0, 1]; CPSNR = 10 log10(1 / MSE) with the
MSE over the three channels of the (optionally cropped) image; the mean CPSNR over images is reported. An image
reproduced exactly (every scored pixel within the compute dtype's rounding, :data:`EXACT_ULPS` ulps of 1, of the truth
as the method received it: a flat image) scores inf; the mean is taken over the others and the exactly reproduced
images are counted beside it (``exact_images``), so that one flat image does not hide every score.

Noisy benchmarks (``noise_sigma``, ``noise_shot``): Poisson-Gaussian noise ``var = a x + sigma^2`` on the [0, 1]
mosaic, drawn by :func:`isettorch.sensor.noise.poisson_gaussian` from a generator seeded by (seed, image index), in
float64 on the CPU (the same noise for every dtype, device and method), not clipped. The sequential baseline
(``denoise``) denoises the mosaic before a classical demosaic: ``nlmeans`` (scikit-image's non-local means, Buades,
Coll & Morel CVPR 2005) or ``bm3d`` (Dabov et al. IEEE TIP 2007; the ``bm3d`` package, installed by the user: its
licence allows non-commercial use only, so it is no dependency of isettorch), each on the four CFA sub-planes
separately, with the generalised Anscombe transform (Makitalo & Foi, IEEE TIP 2013) when the noise is
signal-dependent. The ``learned`` method takes the joint denoise+demosaic network, given the noise level, when noise
is asked for."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import torch

from .._checks import (
    check_device,
    check_finite,
    check_float_dtype,
    check_integer,
    check_seed,
    check_zip_crc,
    first_line,
    is_integer,
    splitmix64,
)
from ..io.images import PHOTO_SUFFIXES, photo_files, read_rgb8, rgb8_to_tensor
from .demosaicing import _LAZY_METHODS, METHODS, demosaic, get_method, mosaic
from .demosaicing._cfa import check_bayer_pattern
from .denoise import DENOISERS, _check_noise, check_denoiser, denoise_mosaic

__all__ = ["DENOISERS", "IMAGE_SUFFIXES", "available_methods", "check_device", "check_photos", "cpsnr",
           "denoise_mosaic", "evaluate_demosaic", "load_demosaic_model", "load_images", "noisy_mosaic", "EXACT_ULPS"]

#: the photographs a folder of images is read from (``isettorch.io.images.PHOTO_SUFFIXES``)
IMAGE_SUFFIXES = PHOTO_SUFFIXES
#: an image is reproduced exactly when every scored pixel is within this many ulps of 1 (the compute dtype's
#: machine epsilon) of its truth: float rounding, 9.5e-7 in float32 (a demosaic error on real content is ~1e-3)
EXACT_ULPS = 8


def available_methods() -> list[str]:
    """Every demosaic method name ``evaluate_demosaic`` accepts: the registry and its lazily imported methods
    (``learned``)."""
    return sorted(set(METHODS) | set(_LAZY_METHODS))


def cpsnr(estimate: torch.Tensor, reference: torch.Tensor, crop: int = 0, peak: float | None = None
          ) -> torch.Tensor:
    """Colour PSNR per image: 10 log10(peak^2 / MSE), the MSE over the three channels and all pixels, a
    ``crop``-pixel border excluded (:func:`isettorch.metrics.fidelity.cpsnr`, with ``crop`` third as the
    benchmarks call it).

    Args:
        estimate, reference: (B, 3, H, W) of the same shape.
        crop: border width excluded on each side (pixels).
        peak: the full scale; None: 1 for floating-point images (a reference outside [0, 1] is refused), 255 for
            uint8.

    Returns:
        (B,) in dB (inf where the images are equal).

    Example:
        >>> est = torch.full((1, 3, 4, 4), 0.5, dtype=torch.float64)
        >>> round(cpsnr(est, est + 0.1).item(), 9)  # MSE 0.01: 10 log10(1 / 0.01) = 20 dB
        20.0
    """
    if estimate.shape != reference.shape or estimate.dim() != 4:
        raise ValueError(f"estimate, reference: expected equal shapes (B, C, H, W), got {tuple(estimate.shape)} "
                         f"and {tuple(reference.shape)}")
    from ..metrics.fidelity import cpsnr as fidelity_cpsnr  # one PSNR implementation (per image, MSE over C, H, W)

    return fidelity_cpsnr(estimate, reference, data_range=peak, crop=crop)


#: the side of the corner of the first image a timed evaluation warms the method up on (pixels)
WARM_UP_PX = 64


def load_images(source: str | Path | Iterable) -> list[tuple[str, np.ndarray]]:
    """8-bit RGB images as (name, uint8 array [H, W, 3]) from a folder (:data:`~isettorch.io.images.PHOTO_SUFFIXES`,
    sorted by name, hidden files left out, an image in another format refused: :func:`isettorch.io.images.photo_files`;
    read by :func:`isettorch.io.images.read_rgb8`: gray, palette and opaque-alpha images converted losslessly,
    anything else refused naming the file) or an iterable of (name, array) pairs."""
    if not isinstance(source, (str, Path)):
        return [(str(n), np.asarray(a)) for n, a in source]
    folder = Path(source)
    if not folder.is_dir():
        raise ValueError(f"images: expected a folder of {'/'.join(PHOTO_SUFFIXES)} images, {str(folder)!r} is not "
                         "a directory")
    try:
        files = photo_files(folder)
    except ValueError as err:
        raise ValueError(f"images: {str(err).removeprefix('folder: ')}") from err
    if not files:
        raise ValueError(f"images: no {'/'.join(PHOTO_SUFFIXES)} files in {str(folder)!r}")
    out = []
    for f in files:
        try:
            out.append((f.name, read_rgb8(f)))
        except ValueError as err:
            raise ValueError(f"images: {err} (in {str(folder)!r})") from err
    return out


def check_photos(items, crop: int, *, min_side: int = 2) -> None:
    """Check every ``(name, array)`` of :func:`load_images` before the first is scored: a uint8 ``[H, W, 3]``
    array, at least ``min_side`` pixels high and wide (one 2 x 2 colour-filter cell: a mosaic and its padding need
    it), and higher and wider than two ``crop``-pixel borders. ValueError naming the image (``images: NAME is W x H
    px ...``, ``crop: NAME is ...``); ``crop`` a non-negative integer."""
    if isinstance(crop, bool) or not isinstance(crop, (int, np.integer)) or crop < 0:
        raise ValueError(f"crop: expected a non-negative integer, got {crop!r}")
    for name, array in items:
        if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] != 3:
            raise ValueError(f"images: expected uint8 arrays [H, W, 3], {name} is {array.dtype} {array.shape}")
        h, w = array.shape[:2]
        if min(h, w) < min_side:
            raise ValueError(f"images: {name} is {w} x {h} px; expected at least {min_side} px each way (a mosaic "
                             f"needs whole 2 x 2 colour-filter cells)")
        if min(h, w) <= 2 * crop:
            raise ValueError(f"crop: {name} is {w} x {h} px, too small for a {crop}-pixel border (at most "
                             f"{(min(h, w) - 1) // 2} for this image)")


def _image_seed(seed: int, index: int) -> int:
    """A 63-bit seed for image ``index`` of a run seeded ``seed`` (splitmix64 finaliser; distinct for distinct
    pairs in practice, independent of the image order of other runs)."""
    return splitmix64(int(seed) * 0x9E3779B97F4A7C15 + int(index) + 1)


def _check_noise_seed(seed) -> int:
    """The noise seed: TypeError for a non-integer (1.5 was 1), ValueError outside ``[0, 2^64)`` (-1 drew the noise of
    2^64 - 1, 2^64 that of 0)."""
    if not is_integer(seed):
        raise TypeError(f"seed: expected an integer, got {seed!r}")
    return check_seed(seed)


def noisy_mosaic(raw: torch.Tensor, noise_sigma: float = 0.0, noise_shot: float = 0.0, *, seed: int = 0,
                 index: int = 0) -> torch.Tensor:
    """The benchmark's noisy mosaic: ``raw`` (B, 1, H, W) in [0, 1] plus noise of variance ``noise_shot * x +
    noise_sigma^2`` (:func:`isettorch.sensor.noise.poisson_gaussian`, Foi et al. 2008), drawn in float64 on the CPU
    from a generator seeded by ``(seed, index)``; returned in ``raw``'s dtype and device, not clipped."""
    from ..sensor.noise import poisson_gaussian

    s, a = _check_noise(noise_sigma, noise_shot)
    _check_noise_seed(seed)
    if not is_integer(index):  # (1.5 was 1)
        raise TypeError(f"index: expected an integer, got {index!r}")
    check_integer(index, "index", 0)
    if not isinstance(raw, torch.Tensor) or not raw.is_floating_point():
        raise TypeError(f"raw: expected a floating-point mosaic tensor (B, 1, H, W) in [0, 1], got "
                        f"{raw.dtype if isinstance(raw, torch.Tensor) else type(raw).__name__}")
    if raw.dim() != 4 or raw.shape[1] != 1:  # ((1, 3, H, W) was taken as a mosaic)
        raise ValueError(f"raw: expected a mosaic (B, 1, H, W), got shape {tuple(raw.shape)}")
    check_finite(raw.detach(), "raw")  # (torch's 'invalid Poisson rate' named nothing)
    if s == 0 and a == 0:
        return raw
    if a > 0 and bool((raw.detach() < 0).any()):  # (named poisson_gaussian's 'signal')
        raise ValueError(f"raw: expected values >= 0 for shot noise (noise_shot {a:g} > 0), got minimum "
                         f"{float(raw.min()):.4g}")
    g = torch.Generator().manual_seed(_image_seed(seed, index))
    x = raw.detach().to("cpu", torch.float64)
    return poisson_gaussian(x, a, s, g).to(device=raw.device, dtype=raw.dtype)


def load_demosaic_model(path: str | Path, class_path: str | None = None, *, kwargs: dict | None = None,
                        device="cpu", dtype=torch.float32) -> torch.nn.Module:
    """A user's demosaic network from ``path``: a TorchScript archive (``torch.jit.save``), a checkpoint of
    :class:`isettorch.isp.learned.DemosaicNet` (``training/train_demosaic.py``), or a state dict of the class
    ``class_path`` (``"package.module:Class"``, built with ``kwargs``). Weights are read with
    ``torch.load(weights_only=True)`` (no pickle). Returned in eval mode on ``device``/``dtype``.

    The network is called as ``net(raw)`` (``raw`` (B, 1, H, W) Bayer mosaic in [0, 1], pattern as evaluated) and
    returns (B, 3, H, W); a :class:`DemosaicNet` with noise inputs is also given the noise level.
    A TorchScript archive holds code: load only your own.
    """
    import importlib
    import zipfile

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model: expected a TorchScript or state-dict file, {str(path)!r} does not exist")
    check_zip_crc(path, "model")
    is_script = False
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as zf:
            is_script = any(n.endswith("constants.pkl") or "/code/" in n for n in zf.namelist())
    if is_script:
        if class_path is not None:
            raise ValueError(f"model_class: {path.name} is a TorchScript archive (it carries its class); "
                             f"got model_class {class_path!r} as well")
        net = torch.jit.load(str(path), map_location="cpu")
        return net.to(device=device, dtype=dtype).eval()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - the file is not a weights-only checkpoint: say what was expected
        raise ValueError(f"model: {str(path)!r} is neither a TorchScript archive nor a weights-only state dict "
                         f"({type(err).__name__}: {first_line(err)})") from err
    if isinstance(state, dict) and "model" in state and "net_config" in state and class_path is None:
        from .learned import load_checkpoint

        return load_checkpoint(path, device=device, dtype=dtype)[0]
    if class_path is None:
        raise ValueError(f"model_class: {path.name} is a state dict; give the network's class as "
                         f"'package.module:Class'")
    if not isinstance(class_path, str) or class_path.count(":") != 1:
        raise ValueError(f"model_class: expected 'package.module:Class', got {class_path!r}")
    mod_name, cls_name = class_path.split(":")
    try:
        cls = getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as err:
        raise ValueError(f"model_class: cannot import {class_path!r} ({err})") from err
    if not isinstance(cls, type):  # ('os:path' is a module: "'module' object is not callable")
        raise ValueError(f"model_class: {class_path!r} is a {type(cls).__name__}, not a class")
    try:
        with torch.random.fork_rng(devices=[]):  # initial weights, replaced by the file's: not the global generator's
            net = cls(**(kwargs or {}))
    except Exception as err:  # noqa: BLE001 - the constructor refused the kwargs: a user error, named
        raise ValueError(f"model_kwargs: {class_path}({kwargs or {}}) failed ({type(err).__name__}: "
                         f"{first_line(err)})") from err
    if not isinstance(net, torch.nn.Module):
        raise ValueError(f"model_class: {class_path!r} does not build a torch.nn.Module")
    if isinstance(state, dict) and "model" in state and isinstance(state["model"], dict):
        state = state["model"]
    try:
        net.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as err:  # missing / unexpected keys, shapes, not a dict
        raise ValueError(f"model: {path.name} does not fit {class_path}({kwargs or {}}): "
                         f"{' '.join(str(err).split())[:300]}") from err
    return net.to(device=device, dtype=dtype).eval()


def evaluate_demosaic(images, method: str | Callable = "bilinear", pattern: str = "RGGB", crop: int = 0, *,
                      dtype: torch.dtype = torch.float32, device="cpu", noise_sigma: float = 0.0,
                      noise_shot: float = 0.0, seed: int = 0, denoise: str | None = None,
                      model: torch.nn.Module | Callable | None = None, progress: bool = False, **kwargs) -> dict:
    """Score a demosaic method on 8-bit images with the benchmark convention (module docstring).

    Args:
        images: a folder of .png/.tif/.jpg 8-bit RGB images (:func:`isettorch.io.images.read_rgb8`), or an
            iterable of (name, uint8 [H, W, 3]) pairs.
        method: a name in :func:`available_methods` or a callable (raw, pattern) -> RGB.
        pattern: Bayer pattern of the simulated mosaic.
        crop: border width excluded from the score (pixels).
        dtype, device: where the demosaic runs (float32 by default: networks are float32).
        noise_sigma, noise_shot: noise ``var = noise_shot x + noise_sigma^2`` on the [0, 1] mosaic (0: none).
        seed: noise seed (image ``i`` uses the generator of ``(seed, i)``).
        denoise: ``None`` or a name in ``DENOISERS``: denoise the mosaic before a classical demosaic.
        model: a network ``net(raw) -> RGB`` (e.g. from :func:`load_demosaic_model`); overrides ``method``.
        progress: show a progress bar (stderr; :func:`isettorch._progress.progress`).
        kwargs: passed to the method.

    Returns:
        {"method", "network", "pattern", "crop", "noise_sigma", "noise_shot", "seed", "denoise", "dtype",
        "mean_cpsnr", "exact_images", "ms_per_image", "ms_per_megapixel", "images": [{"name", "cpsnr", "exact", "ms"},
        ...]}; ``network``: the shipped network the ``learned`` method ran (``"noise_free"``, or ``"joint_denoise"``
        with noise), else None. ms is the wall time of the demosaic (and denoise) call alone, after one warm-up call
        on the first image's top-left corner (:data:`WARM_UP_PX` square).
        An image reproduced exactly (``exact``: within :data:`EXACT_ULPS` ulps of its truth, e.g. a flat image) has
        ``cpsnr`` inf; ``mean_cpsnr`` is the mean over the other images (inf when every image is exact) and
        ``exact_images`` counts the exact ones.
    """
    device = check_device(device)
    # a Bayer string (an index-map tensor had been scored by demosaic_generic's rule under the method's name, and its
    # result's "pattern" was not JSON)
    pattern = check_bayer_pattern(pattern)
    noise_sigma, noise_shot = _check_noise(noise_sigma, noise_shot)
    noisy = noise_sigma > 0 or noise_shot > 0
    check_float_dtype(dtype)
    if noisy:
        _check_noise_seed(seed)  # before the images are read (noisy_mosaic checks it per image)
    if denoise is not None:
        check_denoiser(denoise)  # one of DENOISERS, and runnable here
        if not noisy:
            raise ValueError(f"denoise: {denoise!r} needs noise (noise_sigma or noise_shot > 0)")
        # only what denoises itself: the learned method (its joint network with noise) and a joint model; the
        # noise-free networks (learned_small, learned_tiny, a noise-free model) take a denoised mosaic like a
        # classical method (they were refused: 'the learned method denoises itself')
        if (model is not None and getattr(model, "noise_inputs", False)) or (model is None and method == "learned"):
            raise ValueError(f"denoise: the sequential baseline is for methods that do not denoise; the learned "
                             f"method and a joint model denoise themselves (got denoise {denoise!r} with "
                             f"{'a joint model' if model is not None else 'method ' + repr(method)})")
    if model is not None:
        if not callable(model):
            raise TypeError(f"model: expected a callable network, got {type(model).__name__}")
        name = "model:" + type(model).__name__
    elif isinstance(method, str):
        if method not in available_methods():
            raise ValueError(f"method: expected one of {available_methods()}, got {method!r}")
        get_method(method)
        name = method
    elif callable(method):
        name = type(method).__name__
    else:
        raise TypeError(f"method: expected a method name or a callable, got {type(method).__name__}")
    if kwargs.get("self_ensemble"):
        if model is None and method not in _LAZY_METHODS:
            flag = "--dihedral-ensemble" if kwargs["self_ensemble"] == "dihedral" else "--self-ensemble"
            raise ValueError(f"self_ensemble ({flag}): only for the learned method or a DemosaicNet model, "
                             f"got method {method!r}")
        name += " + self-ensemble" if kwargs["self_ensemble"] in (True, "transpose") else " + dihedral self-ensemble"
    items = load_images(images)
    if not items:  # (nothing scored was reported as mean_cpsnr inf)
        raise ValueError("images: expected at least one (name, image) pair, got none")
    check_photos(items, crop)  # every image before the first is scored (a bad one late in a folder fails early)

    call = _demosaic_call(method, model, pattern, noise_sigma, noise_shot, device, dtype, kwargs)

    def run(raw):
        with torch.no_grad():
            if denoise is not None:
                raw = denoise_mosaic(raw, denoise, noise_sigma, noise_shot)
            out = call(raw)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return out

    from .._progress import progress as progress_bar

    bar = progress_bar(total=len(items), unit="image", desc=f"demosaic-eval {name}", quiet=not progress)
    results, pixels = [], []
    with bar:
        for i, (name_i, array) in enumerate(items):
            truth = rgb8_to_tensor(array)
            try:  # the mosaic and the method: an error says which image
                raw = noisy_mosaic(mosaic(truth, pattern), noise_sigma, noise_shot, seed=seed, index=i)
                raw = raw.to(device=device, dtype=dtype)
                if i == 0:  # warm-up: first-call set-up and kernel selection are not the method's cost; on a
                    # corner of at most 64 x 64 (the CFA phase kept): the whole first image doubled its time (a
                    # 12 MP photograph with the learned method: 171 s instead of 88)
                    run(raw[..., :WARM_UP_PX, :WARM_UP_PX])
                t0 = time.perf_counter()
                out = run(raw)
                ms = 1e3 * (time.perf_counter() - t0)
            except ValueError as err:  # e.g. a learned method on an image under 4 pixels: say which image
                raise ValueError(f"images: {name_i} ({array.shape[1]} x {array.shape[0]} px, W x H): {err}") from err
            except RuntimeError as err:
                if model is None:  # the library's own methods: a bug, not the user's input
                    raise
                # the user's network failed (a TorchScript error, a shape it cannot take): named, not a traceback
                raise ValueError(f"model: {name} failed on {name_i} ({array.shape[1]} x {array.shape[0]} px, W x H): "
                                 f"{' '.join(str(err).split())[:300]}") from err
            label = "model" if model is not None else "method"
            if out.shape != (1, 3) + tuple(truth.shape[-2:]):
                raise ValueError(f"{label}: {name} returned shape {tuple(out.shape)} for a mosaic of "
                                 f"{tuple(raw.shape)}; expected (1, 3, H, W)")
            out = out.to("cpu", torch.float64)
            if not torch.isfinite(out).all():  # clipping would keep a NaN and the score would be NaN: say so
                raise ValueError(f"{label}: {name} returned {int((~torch.isfinite(out)).sum())} NaN/inf values for "
                                 f"{name_i}; expected a finite image")
            # exact: every scored pixel within the compute dtype's rounding (EXACT_ULPS ulps of 1) of the truth as the
            # method received it (code / 255 in dtype); a float32 method reproducing a flat mid-grey scored 140-150 dB
            # of float32 rounding (MSE 1e-16 against the float64 truth) and lifted a folder's mean by 60 dB
            out = out.clamp(0, 1)
            c = int(crop)
            err = (out - truth.to(dtype).to(torch.float64))[..., c:out.shape[-2] - c, c:out.shape[-1] - c]
            exact = float(err.abs().max()) <= EXACT_ULPS * torch.finfo(dtype).eps
            score = math.inf if exact else cpsnr(out, truth, crop)[0].item()
            results.append({"name": name_i, "cpsnr": score, "exact": exact, "ms": ms})
            pixels.append(truth.shape[-2] * truth.shape[-1])
            bar.update(1)
    scored = [r["cpsnr"] for r in results if not r["exact"]]  # (finite: the output is finite and clipped)
    ms_all = [r["ms"] for r in results]
    learned_default = method == "learned" and model is None and "model" not in kwargs
    return {
        "method": name,
        # the shipped network the learned method ran: its joint denoise variant when noise is asked for
        "network": ("joint_denoise" if noisy else "noise_free") if learned_default else None,
        "pattern": pattern,
        "crop": crop,
        "noise_sigma": noise_sigma,
        "noise_shot": noise_shot,
        "seed": int(seed),
        "denoise": denoise,
        "dtype": str(dtype).replace("torch.", ""),
        "mean_cpsnr": float(np.mean(scored)) if scored else math.inf,
        "exact_images": len(results) - len(scored),
        "ms_per_image": float(np.mean(ms_all)),
        "ms_per_megapixel": float(np.sum(ms_all) / (np.sum(pixels) / 1e6)),
        "images": results,
    }


def _demosaic_call(method, model, pattern, noise_sigma, noise_shot, device, dtype, kwargs) -> Callable:
    """raw -> RGB for the chosen method; the learned method (or a DemosaicNet) gets the noise level."""
    from . import learned

    noisy = noise_sigma > 0 or noise_shot > 0
    feats = learned.noise_features(noise_shot, noise_sigma**2).to(device=device, dtype=dtype)
    if model is not None:
        net = model
        if isinstance(net, learned.DemosaicNet):
            return lambda raw: learned.demosaic_learned(raw, pattern, model=net,
                                                        noise=feats if net.noise_inputs else None, **kwargs)
        if kwargs:
            raise ValueError(f"model: options {sorted(kwargs)} are for a DemosaicNet or the learned method, not "
                             f"{type(net).__name__}")
        return lambda raw: net(raw)
    if method == "learned" and "variant" in kwargs:  # (variant='tiny' scored the default network, labelled noise_free)
        raise ValueError(f"variant: the learned method scores the shipped default network (the joint one with noise); "
                         f"for another use method 'learned_small' or 'learned_tiny', got variant {kwargs['variant']!r}")
    if method == "learned" and "model" not in kwargs:
        net = learned.load_pretrained("joint_denoise" if noisy else "noise_free", device=device, dtype=dtype)
        return lambda raw: learned.demosaic_learned(raw, pattern, model=net, noise=feats if noisy else None, **kwargs)
    return lambda raw: demosaic(raw, pattern, method, **kwargs)
