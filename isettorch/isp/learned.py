"""Learned demosaicing: a compact residual CNN on top of Malvar-He-Cutler, trained on synthetic isettorch scenes.

The network (:class:`DemosaicNet`) works on the packed 2x2 Bayer planes at half resolution: its input is the
four raw planes, the space-to-depth Malvar-He-Cutler (MHC) estimate and, for the joint denoise+demosaic variant,
two planes with the noise model's parameters; it predicts a correction of the MHC estimate (12 channels,
depth-to-space back to full resolution). The last layer is zero-initialised, so an untrained network *is* MHC.

``load_pretrained()`` returns the checkpoint shipped in ``isettorch/assets`` (trained by
``training/train_demosaic.py`` on synthetic spectral scenes only, never on Kodak/McMaster; the JSON beside it
records the command, config, data, wall time, hardware and benchmark scores). Inputs are values relative to white
= 1 (white-balanced, linear or display-encoded: both were in the training data). Importing this module registers
the demosaic method ``"learned"`` with :mod:`isettorch.isp.demosaicing` (``demosaic(raw, "RGGB", method="learned")``,
``isettorch demosaic-eval DIR --method learned``, camera configs with ``isp.demosaic: learned``), and the faster
members of its speed-error family, ``"learned_small"`` and ``"learned_tiny"`` (:data:`LEARNED_METHODS`: small
networks correcting Menon et al. 2007 instead of MHC; ``benchmarks/DEMOSAIC_SPEED.md`` has their CPSNR against
milliseconds per megapixel, the Pareto chart in the docs' benchmarks page).

A shipped network runs under a guard (:func:`guard_residual`, :data:`PRETRAINED_GUARDS`): its correction of MHC is
weighted by :func:`structure_gate` (0 where the mosaic has no curvature, relative to its level, that MHC could get
wrong) and high-passed (each channel's local mean stays MHC's). So a constant colour field comes out exactly as MHC
gives it, at any level and colour and for every Bayer phase, and the network adds no channel bias of its own
(issue #35; ``tests/isp/test_learned_guarantees.py``). The network is not scale-equivariant (it was trained at
white = 1); below about 0.3 of white the gate's absolute threshold takes over, so dark mosaics tend to MHC, which is
linear; above white the noise-free networks' corrections fade out (off where a sample within 5 cells reaches 1.5,
``white_fade``), so highlights above white, and a mosaic not normalised to white = 1 (in DN), get the reference.

Before the guard, each shipped configuration may scale the network's correction (:data:`PRETRAINED_CORRECTION_SCALES`)
and blend in a classical estimate (:data:`PRETRAINED_BLENDS`: ``learned`` is 0.7 times its network's output plus 0.3
times Menon et al. 2007's), both chosen on photographs outside the test sets; the guard is linear in what it is given,
so both keep its guarantees.

References:
    H. S. Malvar, L. He, R. Cutler, "High-quality linear interpolation for demosaicing of Bayer-patterned color
    images", ICASSP 2004.
    M. Gharbi, G. Chaurasia, S. Paris, F. Durand, "Deep joint demosaicking and denoising", SIGGRAPH Asia 2016.
"""

from __future__ import annotations

import copy
import functools
import json
import math
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from .._autograd import records_grad, safe_sqrt, tensor_cache
from .._checks import FLOAT_DTYPES, check_bool, check_finite, check_zip_crc, is_real
from ..sensor.cfa import BAYER_PATTERNS  # the one CFA-pattern table
from .demosaicing._cfa import check_bayer_pattern
from .demosaicing.linear import demosaic_malvar2004
from .demosaicing.menon2007 import demosaic_menon2007

__all__ = [
    "BAYER_PATTERNS",
    "DemosaicNet",
    "PRETRAINED_GUARDS",
    "GUARD_REFERENCES",
    "PRETRAINED_CORRECTION_SCALES",
    "PRETRAINED_BLENDS",
    "guard_residual",
    "structure_gate",
    "demosaic_learned",
    "load_pretrained",
    "load_checkpoint",
    "noise_features",
    "mosaic_noise_sigma",
    "level_gate_weight",
    "check_classical_gate",
    "classical_detail_weight",
    "classical_gate_weight",
    "classical_expert",
    "pretrained_info",
    "apply_shipped_settings",
    "PRETRAINED_PATH",
]

ASSETS = Path(__file__).resolve().parent.parent / "assets"
PRETRAINED_PATH = ASSETS / "demosaic_learned.pt"
#: shipped variants: the noise-free network, the joint denoise+demosaic network (noise inputs (a, b)), and the
#: fast noise-free networks of the speed-error family (issue #35: ``learned_tiny``, ``learned_small``)
PRETRAINED = {"noise_free": PRETRAINED_PATH, "joint_denoise": ASSETS / "demosaic_learned_denoise.pt",
              "tiny": ASSETS / "demosaic_learned_tiny.pt", "small": ASSETS / "demosaic_learned_small.pt"}
#: the demosaic methods the shipped noise-free networks register: method name -> variant
LEARNED_METHODS = {"learned": "noise_free", "learned_tiny": "tiny", "learned_small": "small"}
#: the guard each shipped network runs under (:func:`guard_residual`), part of what ``load_pretrained`` returns.
#: The noise-free model's thresholds were chosen on ``training/stress_set.py`` only (no Kodak/McMaster); the joint
#: model keeps its correction wherever the mosaic is not exactly constant (its noise is structure to remove).
#: The noise-free networks' corrections fade out above white (``white_fade`` 1.5, :func:`_white_weight`): trained at
#: white = 1, ``learned`` was 3.1 dB below MHC on a synthetic textured image x 2 (+2.4 above at x 1); with the
#: fade it is +1.1 / +0.2 / +0.0 dB at x 1.5 / 2 / 3, and exactly MHC in a x 3 highlight (audit of 2026-12-03,
#: ``tests/isp/test_learned_guarantees.py``); a mosaic within [0, 1] is unchanged. The joint model has none: noise
#: takes a mosaic near white above it, which is its training domain.
PRETRAINED_GUARDS = {
    "noise_free": {"rel": 0.1, "abs": 0.03, "window": 5, "power": 4, "highpass_sigma_px": 16.0, "white_fade": 1.5},
    "joint_denoise": {"rel": 0.0, "abs": 1e-6, "window": 5, "power": 4, "highpass_sigma_px": 16.0},
    # the fast networks keep the noise-free gate; their high-pass is narrower (at 16 px the tiny network kept
    # 0.17/255 of red bias on a generator scene of the bias test) and computed on 4 x 4 means (the full-resolution
    # sigma-16 blur alone cost ~75 ms/MP on 2 cores with kornia's convolutions, more than the tiny network, and ~30
    # as the shifted sums of _separable); the small network's 4 px chosen on the bias test's images and the stress
    # set's photographs, the tiny network's 8 px (with its gate threshold and correction scale) on the 30 selection
    # photographs (docs/training_log.md#tiny_guard_photos_2026-11-29); never Kodak/McMaster
    "tiny": {"rel": 0.1, "abs": 0.03, "window": 5, "power": 4, "highpass_sigma_px": 8.0, "highpass_decimation": 4,
             "white_fade": 1.5},
    "small": {"rel": 0.1, "abs": 0.03, "window": 5, "power": 4, "highpass_sigma_px": 4.0, "highpass_decimation": 4,
              "white_fade": 1.5},
}
#: the scale of the network's correction in each shipped configuration (``DemosaicNet.correction_scale``; 1 where
#: absent): the networks' corrections learned on synthetic scenes are partly too large for photographs, so each is
#: shrunk towards its base. Chosen on the 30 selection photographs (``training/selection_photos.py``), never
#: Kodak/McMaster: ``docs/training_log.md#fast_shrink_photos_2026-11-29`` (it replaced the earlier choice on the stress
#: set's photographs, ``#fast_shrink_2026-11-28``: small 0.75, tiny 1; the tiny network's chosen again on its
#: unrefined base, ``#tiny_norefine_2026-11-29``, and with its guard, ``#tiny_guard_photos_2026-11-29``) and
#: ``#learned_scale_photos_2026-11-29`` (the noise-free network, also the joint network's low-noise expert). The joint
#: network keeps 1: its correction is a denoiser's too.
PRETRAINED_CORRECTION_SCALES = {"small": 0.5, "tiny": 0.5, "noise_free": 0.875}
#: the classical estimate each shipped configuration blends in (``DemosaicNet.blend``; none where absent): the output
#: is ``(1 - weight) net_output + weight classical_output``, the classical method's departure from the network's base
#: guarded like the network's correction (so the guarantees hold). Two estimators that err differently: the
#: noise-free network is below Menon 2007 on a few photographs and Menon within 0.5 dB of it on Kodak. Chosen on the 30
#: selection photographs (``training/selection_photos.py``), never Kodak/McMaster:
#: ``docs/training_log.md#menon_blend_photos_2026-11-29``.
PRETRAINED_BLENDS = {"noise_free": {"method": "menon2007", "weight": 0.3}}
#: the low-noise gate each shipped joint network runs under, part of what ``load_pretrained`` returns (issue #35 item
#: 4: the joint network is tuned for mid noise, the noise-free network is better on nearly clean mosaics): the output
#: is ``w expert + (1 - w) joint`` with ``w = clamp(1 - r / relative_max, 0, 1)`` per image, ``r = sqrt(b + a m) / m``
#: the noise of a mosaic ``x`` with noise variance ``a x + b`` (the level the joint network is given) against its mean
#: level ``m`` (:func:`level_gate_weight`), the same for a frame at any exposure. ``relative_max`` was chosen on
#: held-out synthetic scenes at two exposures (``docs/training_log.md#relative_gate_round2_2026-11-28``; it replaced
#: the absolute ``sigma_max = 0.0125`` of ``#joint_gate_2026-11-28``, which weighed the noise-free network into
#: underexposed frames), never Kodak/McMaster.
#: Its high-noise gate (``classical``) then blends in a classical expert (:func:`classical_expert`: nlmeans, then
#: Menon 2007), which errs differently from the network: ``w expert + (1 - w) out`` per pixel, with
#: ``w = ramp (weight_detail + (weight_max - weight_detail) flat)``: ``ramp = clamp((sigma - sigma_start) /
#: (sigma_full - sigma_start), 0, 1)`` of the mosaic's noise at its mean level (:func:`classical_gate_weight`,
#: ``sigma = sqrt(b + a m)``; 0 on a noise-free mosaic) and ``flat`` 1 where the mean of the two estimates is flat
#: within its local noise, 0 on detail (:func:`classical_detail_weight`, ``detail_r``): on photographs the non-local
#: search denoises flat regions far better than the network and the network keeps detail better. Chosen on the 30
#: selection photographs with the held-out synthetic sets as a check, never Kodak/McMaster
#: (``docs/training_log.md#classical_detail_gate_2026-11-30``; it replaced one weight per image, ``sigma_start``
#: 0.005, ``sigma_full`` 0.075, ``weight_max`` 0.5, chosen on synthetic scenes: ``#classical_gate_2026-11-28``,
#: ``#classical_gate_refit_2026-11-28``). The expert runs on every noisy mosaic (nlmeans on the CPU).
PRETRAINED_GATES = {"joint_denoise": {
    "expert": "noise_free", "relative_max": 0.0375,
    "classical": {"sigma_start": 0.0, "sigma_full": 0.01, "weight_max": 1.0, "weight_detail": 0.2,
                  "detail_r": (0.25, 1.0), "denoiser": "nlmeans", "method": "menon2007"}}}

def _check_raw(raw: torch.Tensor, name: str = "raw", even: bool = True) -> torch.Tensor:
    if not isinstance(raw, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor [B, 1, H, W], got {type(raw).__name__}")
    if raw.dim() == 2:  # one mosaic [H, W]
        raw = raw[None, None]
    # (a [B, H, W] batch was taken too: an RGB image [3, H, W] given by mistake came back as three mosaics)
    if raw.dim() != 4 or raw.shape[1] != 1:
        raise ValueError(f"{name}: expected shape [B, 1, H, W] (or one mosaic [H, W]), got {tuple(raw.shape)}")
    if raw.dtype not in FLOAT_DTYPES:  # (float16 / bfloat16 lose the colour differences the
        # networks correct: learned_tiny was off by 0.7 on a float16 mosaic; under autocast the input stays float32)
        raise TypeError(f"{name}: expected a float32 or float64 tensor, got {raw.dtype}")
    if raw.shape[-2] < 4 or raw.shape[-1] < 4:
        raise ValueError(f"{name}: expected a height and width of at least 4, got {tuple(raw.shape[-2:])}")
    if even and (raw.shape[-2] % 2 or raw.shape[-1] % 2):
        raise ValueError(f"{name}: expected an even height and width (whole 2 x 2 Bayer cells; demosaic_learned "
                         f"takes any size), got {tuple(raw.shape[-2:])}")
    return raw


def _to_rggb(raw: torch.Tensor, pattern: str) -> tuple[torch.Tensor, int, int]:
    """Reflect-pad one row/column so the mosaic starts with an R pixel; returns the offsets to crop back."""
    dy = 1 if pattern in ("GBRG", "BGGR") else 0
    dx = 1 if pattern in ("GRBG", "BGGR") else 0
    if dy or dx:
        raw = F.pad(raw, (dx, dx, dy, dy), mode="reflect")
    return raw, dy, dx


def _curvature(planes: torch.Tensor) -> torch.Tensor:
    """The mean over the planes (B, C, h, w) of ``|d2/dx2| + |d2/dy2|`` by slicing (exactly 0 on a constant plane,
    whatever its value, since ``(c + c) - 2c`` is exact in floating point), each edge row/column repeating its
    neighbour's; (B, 1, h, w)."""
    b, _, h, w = planes.shape
    out = planes.new_zeros(b, 1, h, w) if w < 3 else F.pad(
        (planes[..., 2:] + planes[..., :-2]).sub_(planes[..., 1:-1], alpha=2).abs().mean(1, keepdim=True),
        (1, 1, 0, 0), mode="replicate")
    if h >= 3:
        dyy = (planes[..., 2:, :] + planes[..., :-2, :]).sub_(planes[..., 1:-1, :], alpha=2).abs().mean(1, keepdim=True)
        out[..., 1:-1, :] += dyy  # dyy padded by repeating its first and last rows, added in place
        out[..., :1, :] += dyy[..., :1, :]
        out[..., -1:, :] += dyy[..., -1:, :]
    return out


def _separable(x: torch.Tensor, taps: list[float]) -> torch.Tensor:
    """Correlation of every channel with ``taps`` (odd length) along the height, then along the width, replicate
    border, summed as shifted slices: several times faster on CPU than a depthwise ``conv2d`` (whose CPU path is
    slow for a few channels) or ``avg_pool2d``'s stride-1 window, at any size (4.7x at 97 taps on 768 x 512)."""
    p = len(taps) // 2
    x = F.pad(x, (p, p, p, p), mode="replicate")
    h, w = x.shape[-2] - 2 * p, x.shape[-1] - 2 * p
    rows = x[..., :h, :] * taps[0]
    for k in range(1, len(taps)):
        rows.add_(x[..., k:k + h, :], alpha=taps[k])
    out = rows[..., :w] * taps[0]
    for k in range(1, len(taps)):
        out.add_(rows[..., k:k + w], alpha=taps[k])
    return out


def _box(x: torch.Tensor, window: int) -> torch.Tensor:
    """``window`` x ``window`` local mean, replicate border: the same as ``avg_pool2d`` of the padded input
    (:func:`_separable`)."""
    return _separable(x, [1.0] * window).div_(window * window)


#: the classical demosaic a :class:`DemosaicNet` corrects (``base=``), each on an RGGB mosaic with mirrored borders
BASES = {
    "malvar2004": lambda raw: demosaic_malvar2004(raw, "RGGB", boundary="mirror"),
    "menon2007": lambda raw: demosaic_menon2007(raw, "RGGB"),
    # Menon et al. (2007) without the paper's refining step (colour-demosaicing's ``refining_step=False``): that
    # step is about a third of Menon's CPU time here, and a network on top can learn what it does
    "menon2007_norefine": lambda raw: demosaic_menon2007(raw, "RGGB", refine=False),
}

_GUARD_KEYS = ("rel", "abs", "window", "power", "highpass_sigma_px", "highpass_decimation", "white_fade", "reference")
#: what a :class:`DemosaicNet`'s guard keeps where it gates the correction off (its ``guard["reference"]``): MHC
#: (the default: linear, exact on constants, unbiased) or the network's own ``base`` (exact on constants too for
#: every base in :data:`BASES`, and not computed twice)
GUARD_REFERENCES = ("malvar2004", "base")


def _split_guard(guard: dict) -> tuple[dict, str]:
    """A network's guard options as :func:`guard_residual` takes them, and its reference (:data:`GUARD_REFERENCES`)."""
    opts = dict(guard)
    reference = opts.pop("reference", "malvar2004")
    if reference not in GUARD_REFERENCES:
        raise ValueError(f"guard: expected reference one of {GUARD_REFERENCES}, got {reference!r}")
    return opts, reference


def _check_guard(rel=0.1, abs=0.03, window=5, power=4.0, highpass_sigma_px=None,  # noqa: A002
                 highpass_decimation=None, white_fade=None) -> None:
    if white_fade is not None and not (is_real(white_fade) and 1 < float(white_fade) < math.inf):
        raise ValueError(f"white_fade: expected None or a finite level above white (1), got {white_fade!r}")
    if not (float(rel) >= 0 and float(abs) > 0):
        raise ValueError(f"rel, abs: expected rel >= 0 and abs > 0 (abs keeps the gate defined on black), got "
                         f"{rel}, {abs}")
    if int(window) != window or window < 1 or window % 2 == 0:
        raise ValueError(f"window: expected an odd number of half-resolution pixels >= 1, got {window}")
    if not float(power) > 0:
        raise ValueError(f"power: expected > 0, got {power}")
    if highpass_sigma_px is not None and not float(highpass_sigma_px) > 0:
        raise ValueError(f"highpass_sigma_px: expected a Gaussian sigma > 0 in pixels or None, got {highpass_sigma_px}")
    if highpass_decimation is not None and (isinstance(highpass_decimation, bool) or
                                            int(highpass_decimation) != highpass_decimation or
                                            highpass_decimation < 2):
        raise ValueError(f"highpass_decimation: expected an integer factor >= 2 or None, got {highpass_decimation!r}")
    if highpass_decimation is not None and highpass_sigma_px is not None and highpass_sigma_px < highpass_decimation:
        raise ValueError(f"highpass_decimation: expected a factor <= highpass_sigma_px ({highpass_sigma_px}), got "
                         f"{highpass_decimation}")


def _gaussian_blur(x: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """kornia's ``gaussian_blur2d`` of ``sigma_px`` (its kernel, ``get_gaussian_kernel1d`` of ``2 ceil(3 sigma) + 1``
    taps, and its replicate border) by :func:`_separable`: the same values to float rounding, 5-8x faster on CPU
    than kornia's depthwise convolutions."""
    return _separable(x, _gaussian_taps(float(sigma_px)))


@functools.lru_cache(maxsize=64)
def _gaussian_taps(sigma_px: float) -> tuple[float, ...]:
    """kornia's ``get_gaussian_kernel1d`` of ``2 ceil(3 sigma) + 1`` taps as floats (cached: ~0.3 ms a call)."""
    from kornia.filters import get_gaussian_kernel1d

    k = 2 * math.ceil(3 * sigma_px) + 1
    return tuple(get_gaussian_kernel1d(k, sigma_px, dtype=torch.float64)[0].tolist())


def _lowpass(x: torch.Tensor, sigma_px: float, decimation: int | None) -> torch.Tensor:
    """Gaussian blur of ``sigma_px`` (replicate border); with ``decimation`` d, the blur is computed on the
    d x d box means (``sigma_px / d`` there) and brought back by bilinear interpolation: the pyramid shortcut of
    Burt & Adelson (IEEE Trans. Commun. 1983), about 10x cheaper at sigma 16, d 8, and the same scale of local mean
    (the box and the interpolation add about d / sqrt(6) px in quadrature to sigma)."""
    if decimation is None:
        return _gaussian_blur(x, sigma_px)
    h, w = x.shape[-2:]
    big = F.interpolate(_decimated_blur(x, sigma_px, int(decimation)), scale_factor=int(decimation),
                        mode="bilinear", align_corners=False)
    return big[..., :h, :w]


def _decimated_blur(x: torch.Tensor, sigma_px: float, d: int) -> torch.Tensor:
    """:func:`_lowpass`'s blur of the d x d box means (the input extended to a multiple of d by replicating its last
    row and column): (B, C, ceil(H / d), ceil(W / d))."""
    h, w = x.shape[-2:]
    ph, pw = -h % d, -w % d
    small = F.avg_pool2d(F.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x, d)
    return _gaussian_blur(small, sigma_px / d)


def _highpass_(x: torch.Tensor, sigma_px: float, decimation: int | None) -> torch.Tensor:
    """``x -= _lowpass(x, sigma_px, decimation)`` in place (no autograd), returned. With ``decimation`` d the bilinear
    interpolation of the blurred d x d means is subtracted as it is computed, one output row phase (and, on the small
    image, one column phase) at a time, as two scaled subtractions of contiguous rows: no full-resolution temporary,
    and 2.9x faster than ``F.interpolate`` then ``sub_`` (1.7 against 5.0 ms/MP, 3 channels, d 4, 2 threads, AVX2).
    The weights are ``F.interpolate``'s (``align_corners=False``: output i reads source (i + 1/2) / d - 1/2, clamped
    to the image, which the replicated border gives); the same values to float rounding
    (``tests/isp/test_learned_family.py``)."""
    if decimation is None:
        return x.sub_(_gaussian_blur(x, sigma_px))
    d = int(decimation)
    h, w = x.shape[-2:]
    small = F.pad(_decimated_blur(x, sigma_px, d), (1, 1, 1, 1), mode="replicate")
    phases = [((p + 0.5) / d - 0.5) for p in range(d)]  # each phase's offset from its source sample, in (-1/2, 1/2)
    # along the width, on the small image's rows (and its padding rows): (B, C, ceil(H / d) + 2, W)
    wide = small.new_empty(*small.shape[:-1], w)
    for p, f in enumerate(phases):
        n = len(range(p, w, d))
        k0 = 0 if f < 0 else 1  # between padded columns k0 + k and k0 + k + 1, at 1 + f or f
        torch.lerp(small[..., k0:k0 + n], small[..., k0 + 1:k0 + 1 + n], 1 + f if f < 0 else f, out=wide[..., p::d])
    for p, f in enumerate(phases):  # along the height, subtracted from x's rows of this phase
        n = len(range(p, h, d))
        k0, t = (0, 1 + f) if f < 0 else (1, f)
        x[..., p::d, :].sub_(wide[..., k0:k0 + n, :], alpha=1 - t).sub_(wide[..., k0 + 1:k0 + 1 + n, :], alpha=t)
    return x


def structure_gate(raw: torch.Tensor, rel: float = 0.1, abs: float = 0.03, window: int = 5,  # noqa: A002
                   power: float = 4.0) -> torch.Tensor:
    """Where an RGGB mosaic has structure that Malvar-He-Cutler can get wrong: a weight in [0, 1] per pixel.

    MHC is exact wherever every colour channel is locally affine (its bilinear terms are exact on affine
    signals and its Laplacian corrections vanish on them; Malvar, He & Cutler 2004), so its error is driven by
    curvature. The structure ``s`` is the local mean (``window`` x ``window`` half-resolution pixels) over the four
    Bayer planes of ``|d2/dx2| + |d2/dy2|`` of each plane; the level ``L`` is the largest plane's local mean. The
    gate is ``s^p / (s^p + (rel L)^p + abs^p)``: 0 exactly on a constant colour field of any value (all second
    differences are exact zeros), near 0 where the mosaic is smooth relative to its level or very dark, near 1
    on texture. With ``abs`` small against ``rel L`` the gate is invariant to a brightness scaling of the mosaic.

    Args:
        raw: (B, 1, H, W) RGGB mosaic, H and W even.
        rel, abs: the thresholds relative to the level and absolute (values of the mosaic; ``abs`` > 0).
        window: odd box width in half-resolution pixels.
        power: sharpness ``p`` of the transition.

    Returns:
        (B, 1, H, W), each 2 x 2 Bayer cell one value.
    """
    _check_guard(rel, abs, window, power)
    return _pixel_gate(raw, rel, abs, window, power)


def _pixel_gate(raw: torch.Tensor, rel: float, abs: float, window: int, power: float,  # noqa: A002
                white_fade: float | None = None) -> torch.Tensor:
    """:func:`structure_gate` on options already checked: each cell's value copied to its four pixels; with
    ``white_fade``, times :func:`_white_weight`."""
    gate = _cell_gate(raw, rel, abs, window, power)
    if white_fade is not None:
        gate = gate * _white_weight(raw, window, white_fade).to(gate.dtype)
    return F.interpolate(gate, scale_factor=2, mode="nearest")


def _white_weight(raw: torch.Tensor, window: int, white_fade: float) -> torch.Tensor:
    """Per 2 x 2 cell (B, 1, H/2, W/2): 1 where no sample within ``window`` cells is above white (1, the level the
    networks were trained at), falling linearly to 0 where the largest reaches ``white_fade``. The networks are not
    scale-equivariant: above white their corrections were measured below MHC (``learned`` on a textured image x 1.5:
    -0.48 dB, x 2: -3.1 dB, x 3: -4.7 dB, and +0.13/255 of red bias; audit of 2026-12-03)."""
    peak = F.max_pool2d(F.pixel_unshuffle(raw, 2).amax(1, keepdim=True), window, stride=1, padding=window // 2)
    return ((white_fade - peak) / (white_fade - 1)).clamp_(0, 1)


def _cell_gate(raw: torch.Tensor, rel: float, abs: float, window: int, power: float) -> torch.Tensor:  # noqa: A002
    """:func:`structure_gate` at half resolution, one value per 2 x 2 Bayer cell: (B, 1, H/2, W/2)."""
    planes = F.pixel_unshuffle(raw, 2)
    s = _box(_curvature(planes), window)
    level = _box(planes, window).amax(1, keepdim=True)
    # s^p / (s^p + t^p + a^p) with the three divided by the largest of them first (a > 0): the powers of large
    # values overflowed to inf / inf = NaN (a float16 mosaic from 32, float32 from ~1e9); 0 exactly where s = 0
    t = (rel * level).abs()
    m = torch.maximum(torch.maximum(s, t), torch.full_like(s, float(abs)))
    sp, tp, ap = _pow(s / m, power), _pow(t / m, power), _pow(float(abs) / m, power)
    return sp / (sp + tp + ap)


def _pow(x: torch.Tensor, power: float) -> torch.Tensor:
    """``x ** power`` for ``x >= 0``; the shipped power 4 as two squares (the same to 2e-7 relative, and 14x faster on
    CPU than ``pow`` with a float exponent: 21 against 283 us on 0.1 M values, 2 threads, AVX2)."""
    if power == 4:
        return x.square().square_()
    return x.pow(power)


def guard_residual(raw: torch.Tensor, residual: torch.Tensor, *, rel: float = 0.1, abs: float = 0.03,  # noqa: A002
                   window: int = 5, power: float = 4.0, highpass_sigma_px: float | None = 16.0,
                   highpass_decimation: int | None = None, white_fade: float | None = None,
                   in_place: bool = False) -> torch.Tensor:
    """The guarded correction of a network on top of MHC: ``highpass(structure_gate(raw) * residual)``.

    The gate (:func:`structure_gate`) leaves MHC where the mosaic has no structure that MHC can get wrong, so a
    constant colour field is reproduced as exactly as MHC reproduces it (to float rounding) at any level and
    colour; the high-pass (the correction minus its Gaussian blur of ``highpass_sigma_px`` pixels, replicate
    border; ``None``: none) keeps each channel's local mean MHC's, so the network adds no colour bias of its own
    (MHC, being linear and exact on constants, has none in expectation). The mosaic's own samples, which a
    noise-free network does not correct, are moved by the high-pass's blur of the correction (up to 0.014 of full
    scale on a 128 x 128 photograph for ``learned``, 0.025 / 0.016 for ``learned_small`` / ``learned_tiny``, 0.06 on
    small crops and up to 0.26 on 4 x 4 inputs; audits of 2026-12-01): the shipped learned methods do not return the
    measured samples exactly, as MHC and Menon do. ``highpass_decimation`` d computes that blur on d x d means
    (:func:`_lowpass`), for the fast networks where the full-resolution blur would cost more than the network; those
    means are anchored at the image's origin, so the fast networks are equivariant to shifts of 4 pixels only (a crop
    at offset 2 changes the interior by up to 5e-3; tiles processed apart show seams unless their origins are
    multiples of 4).

    Args:
        raw: (B, 1, H, W) RGGB mosaic.
        residual: (B, 3, H, W) the network's correction of MHC.
        white_fade: None, or the level above white (1) at which the correction is off: between 1 and it, the gate is
            scaled down linearly with the largest sample within ``window`` cells (:func:`_white_weight`), so a
            highlight above white, or a mosaic not normalised to white = 1 (DN), gets the reference (MHC).
        in_place: write the result over ``residual`` (which no autograd graph may record), with no full-resolution
            temporary but the gate's one plane (:class:`DemosaicNet` does so in inference; with ``highpass_decimation``
            the low-pass is subtracted as it is interpolated, :func:`_highpass_`).

    Returns:
        (B, 3, H, W) the guarded correction.
    """
    _check_guard(rel, abs, window, power, highpass_sigma_px, highpass_decimation, white_fade)
    # each 2 x 2 cell's weight copied to its four pixels, one plane (multiplying through a broadcast view of the
    # cells instead, inner dimension 2, takes 4.1 against 1.0 ms/MP on 3 channels, 2 threads, AVX2)
    gate = _pixel_gate(raw, rel, abs, window, power, white_fade).to(residual.dtype)
    if in_place:
        out = residual.mul_(gate)
        return out if highpass_sigma_px is None else _highpass_(out, float(highpass_sigma_px), highpass_decimation)
    out = residual * gate
    if highpass_sigma_px is not None:
        out = out - _lowpass(out, float(highpass_sigma_px), highpass_decimation)
    return out


def _check_blend(blend: dict | None) -> dict | None:
    if blend is None:
        return None
    if not isinstance(blend, dict) or set(blend) != {"method", "weight"}:
        raise ValueError(f"blend: expected None or {{'method': one of {sorted(BASES)}, 'weight': b in [0, 1]}}, got "
                         f"{blend!r}")
    w = blend["weight"]
    if (not isinstance(blend["method"], str) or blend["method"] not in BASES or isinstance(w, bool)
            or not isinstance(w, (int, float)) or not 0 <= w <= 1):
        raise ValueError(f"blend: expected method one of {sorted(BASES)} and a weight in [0, 1], got {blend!r}")
    return {"method": blend["method"], "weight": float(w)}


class DemosaicNet(nn.Module):
    """Residual demosaic (and optionally denoise) CNN on packed Bayer planes; corrects the MHC estimate.

    Args:
        channels: width of the hidden layers.
        depth: number of hidden 3x3 conv layers at half resolution (>= 1).
        noise_inputs: number of per-image noise parameters fed as constant planes (0 for noise-free).
        residual: after the first layer, pairs of conv layers with identity shortcuts (``x + conv(relu(conv(x)))``,
            the residual blocks of He et al., CVPR 2016, without batch norm as in EDSR, Lim et al. 2017), so a deep
            body trains as fast as a shallow one; ``depth - 1`` must then be even. Default False: a plain stack
            (the earlier checkpoints).
        base: the classical estimate the network corrects (:data:`BASES`): ``"malvar2004"`` (MHC, linear, the
            default and every network before the speed family), ``"menon2007"`` (DDFAPD, Menon et al. 2007: about
            4x MHC's time and 3.5 dB better on Kodak, so a small network on top of it starts higher) or
            ``"menon2007_norefine"`` (the same without its refining step: two thirds of its time, for the tiny
            network, which learned what the step does). The guard is
            always relative to MHC: with another base it guards the network's whole departure from MHC (base plus
            correction minus MHC), so constants stay exact and the output's local means MHC's.
        guard: ``None`` (training: the raw correction) or the options of :func:`guard_residual` (a dict), which
            then guards the correction in ``forward``: exact on constant colour fields, no colour bias of its own.
            :func:`load_pretrained` sets the shipped one (:data:`PRETRAINED_GUARDS`). May be changed on an instance.
            Its option ``reference`` (:data:`GUARD_REFERENCES`) is what the guard keeps where it gates the correction
            off: ``"malvar2004"`` (the default, every shipped network) or ``"base"`` (the network's base, no MHC
            pass; with Menon as the base it falls below MHC on smooth, dark and single-hue images:
            ``docs/training_log.md#tiny_guard_reference_2026-11-29``).
        correction_scale: the network's correction is multiplied by this before it is added to the base (and
            guarded): 1 (training, the default) the network as trained, 0 the base alone (guarded). The output is
            ``base + guard(base - MHC + s net)`` with another base than MHC. :func:`load_pretrained` sets the
            shipped value (:data:`PRETRAINED_CORRECTION_SCALES`). May be changed on an instance.
        blend: ``None`` (the default) or ``{"method": name, "weight": b}`` with ``name`` one of :data:`BASES` and
            ``0 <= b <= 1``: the output becomes ``(1 - b)`` times the network's output plus ``b`` times that classical
            method's, before the guard (which is linear, so the blend of two guarded estimates): the correction
            given to the guard is ``(1 - b) s net + b (classical - base)``. :func:`load_pretrained` sets the shipped
            one (:data:`PRETRAINED_BLENDS`). May be changed on an instance.

    Shapes:
        forward(raw (B, 1, H, W) RGGB, noise (B, noise_inputs) optional) -> (B, 3, H, W).

    Example:
        >>> net = DemosaicNet(channels=16, depth=2)
        >>> net(torch.rand(2, 1, 16, 16)).shape
        torch.Size([2, 3, 16, 16])
    """

    def __init__(self, channels: int = 48, depth: int = 6, noise_inputs: int = 0, residual: bool = False,
                 guard: dict | None = None, base: str = "malvar2004", correction_scale: float = 1.0,
                 blend: dict | None = None):
        super().__init__()
        self.blend = _check_blend(blend)
        if not (isinstance(correction_scale, (int, float)) and not isinstance(correction_scale, bool)
                and math.isfinite(correction_scale) and correction_scale >= 0):
            raise ValueError(f"correction_scale: expected a finite number >= 0, got {correction_scale!r}")
        self.correction_scale = float(correction_scale)
        if base not in BASES:
            raise ValueError(f"base: expected one of {sorted(BASES)}, got {base!r}")
        self.base = base
        if guard is not None:
            if not isinstance(guard, dict):
                raise TypeError(f"guard: expected None or a dict of guard_residual options, got {type(guard).__name__}")
            if set(guard) - set(_GUARD_KEYS):
                raise ValueError(f"guard: unknown options {sorted(set(guard) - set(_GUARD_KEYS))}, expected some of "
                                 f"{_GUARD_KEYS}")
            _check_guard(**_split_guard(guard)[0])
        self.guard = dict(guard) if guard is not None else None
        if int(channels) < 1 or int(depth) < 1 or int(noise_inputs) < 0:
            raise ValueError(f"channels, depth, noise_inputs: expected >=1, >=1, >=0, got {channels}, {depth}, "
                             f"{noise_inputs}")
        if residual and (int(depth) - 1) % 2:
            raise ValueError(f"depth: a residual body is one layer plus pairs of layers, expected an odd depth, "
                             f"got {depth}")
        self.channels, self.depth, self.noise_inputs = int(channels), int(depth), int(noise_inputs)
        self.residual = bool(residual)
        layers: list[nn.Module] = [nn.Conv2d(4 + 12 + self.noise_inputs, self.channels, 3, padding=1),
                                   nn.ReLU(inplace=True)]
        if self.residual:
            layers += [_ResidualBlock(self.channels) for _ in range((self.depth - 1) // 2)]
        else:
            for _ in range(self.depth - 1):
                layers += [nn.Conv2d(self.channels, self.channels, 3, padding=1), nn.ReLU(inplace=True)]
        self.body = nn.Sequential(*layers)
        for m in self.body.modules():  # He et al. (ICCV 2015) init keeps the ReLU activations' scale through
            if isinstance(m, nn.Conv2d):  # any depth (PyTorch's default shrinks them ~1/sqrt(3) per layer)
                nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
                nn.init.zeros_(m.bias)
        for m in self.body.modules():  # each residual branch starts small: the body starts near its first layer
            if isinstance(m, _ResidualBlock):
                m.conv2.weight.data.mul_(0.1)
        self.head = nn.Conv2d(self.channels, 12, 3, padding=1)
        nn.init.zeros_(self.head.weight)  # start exactly at MHC
        nn.init.zeros_(self.head.bias)

    def config(self) -> dict:
        cfg = {"channels": self.channels, "depth": self.depth, "noise_inputs": self.noise_inputs}
        if self.residual:  # plain networks keep the config (and checkpoints) they always had
            cfg["residual"] = True
        if self.guard is not None:
            cfg["guard"] = dict(self.guard)
        if self.base != "malvar2004":
            cfg["base"] = self.base
        if self.correction_scale != 1.0:
            cfg["correction_scale"] = self.correction_scale
        if self.blend is not None:
            cfg["blend"] = dict(self.blend)
        return cfg

    def _apply(self, fn, *args, **kwargs):
        # .to / .double / .cuda move the low-noise gate's expert network too (load_pretrained('joint_denoise')
        # keeps it in the plain dict level_gate: after .double() it stayed float32 and demosaic_learned failed)
        super()._apply(fn, *args, **kwargs)
        expert = (getattr(self, "level_gate", None) or {}).get("expert")
        if isinstance(expert, nn.Module):
            expert._apply(fn, *args, **kwargs)
        return self

    def forward(self, raw: torch.Tensor, noise: torch.Tensor | None = None) -> torch.Tensor:
        raw = _check_raw(raw)
        # the MHC base at the input's precision even under autocast (a bfloat16 base would cap the output's
        # accuracy at ~2^-9 of the signal); only the residual body runs at the autocast precision
        with torch.autocast(raw.device.type, enabled=False):
            base = BASES[self.base](raw)
        if self.noise_inputs:
            if noise is None:
                noise = torch.zeros(raw.shape[0], self.noise_inputs, dtype=raw.dtype, device=raw.device)
            noise = torch.as_tensor(noise, dtype=raw.dtype, device=raw.device).reshape(raw.shape[0], -1)
            if noise.shape[1] != self.noise_inputs:
                raise ValueError(f"noise: expected shape [B, {self.noise_inputs}], got {tuple(noise.shape)}")
        elif noise is not None:
            raise ValueError("noise: this network was built with noise_inputs=0; pass noise=None")
        # oneDNN's CPU convolutions run about 1.4x faster on channels-last (NHWC) activations; the values are the same
        grad = records_grad(raw, noise, self)
        x = self.body[1:](_first_conv(self.body[0], raw, base, noise, channels_last=raw.device.type == "cpu",
                                      fold_raw=not grad))
        blend = _check_blend(self.blend) if self.blend is not None else None  # an instance's blend may have changed
        if grad:
            return self._output(raw, base, self.head(x), blend)
        return self._output_in_place(raw, base, x, blend)

    def _output(self, raw: torch.Tensor, base: torch.Tensor, y: torch.Tensor, blend: dict | None) -> torch.Tensor:
        """The output from the head's packed correction ``y`` when autograd records the pass (training): each step
        into a fresh tensor."""
        residual = _unpack(y).to(base.dtype)
        if self.correction_scale != 1.0:
            residual = residual * self.correction_scale
        with torch.autocast(raw.device.type, enabled=False):  # the classical estimates at the input's precision
            if blend is not None:
                departure = BASES[blend["method"]](raw) - base
                residual = (1 - blend["weight"]) * residual + blend["weight"] * departure
            if self.guard is not None:
                opts, reference = _split_guard(self.guard)
                if reference == "malvar2004" and self.base != "malvar2004":
                    # the guard is relative to MHC (linear, exact on constants, unbiased) whatever the base: the
                    # network's output minus MHC is the correction it guards (Menon's own decisions are not linear:
                    # -0.32/255 of blue bias on a star field), so the guarantees hold for every base
                    mhc = BASES["malvar2004"](raw)
                    residual = residual + (base - mhc)
                    base = mhc
                residual = guard_residual(raw, residual, **opts)
        return base + residual

    def _output_in_place(self, raw: torch.Tensor, base: torch.Tensor, x: torch.Tensor, blend: dict | None
                         ) -> torch.Tensor:
        """:meth:`_output` when autograd records nothing (inference), the same sums in another order (float
        rounding, ~1e-7): the correction scale and the blend's network weight are folded into the head's weights,
        the classical departures are summed into one of the fresh classical estimates, the head's correction is
        added to it as it is unpacked, and the guard writes over it. Each full-resolution pass written into a fresh
        tensor costs about as much on CPU as the arithmetic (its pages are new), so this saves three of them."""
        k = self.correction_scale * (1 - blend["weight"] if blend is not None else 1.0)
        y, channels = _head_forward(self.head, x, k)
        y = y.to(base.dtype)
        with torch.autocast(raw.device.type, enabled=False):
            add = None  # the classical part of the correction (a fresh tensor), or None
            if blend is not None:
                add = BASES[blend["method"]](raw).sub_(base).mul_(blend["weight"])
            opts, reference = _split_guard(self.guard) if self.guard is not None else (None, None)
            if reference == "malvar2004" and self.base != "malvar2004":  # relative to MHC (_output)
                mhc = BASES["malvar2004"](raw)
                add = base.sub_(mhc) if add is None else add.add_(base).sub_(mhc)  # (base: a fresh estimate)
                base = mhc
            residual = _unpack(y, add_to=add, channels=channels)
            if opts is not None:
                residual = guard_residual(raw, residual, **opts, in_place=True)
        return residual.add_(base)


def _first_conv(conv: nn.Conv2d, raw: torch.Tensor, base: torch.Tensor, noise: torch.Tensor | None,
                channels_last: bool, fold_raw: bool = False) -> torch.Tensor:
    """The network's first layer, ``conv`` (3 x 3, padding 1) on its packed input (the mosaic's and the base's
    2 x 2 cells as channels in ``pixel_unshuffle``'s order, then the N noise inputs as constant planes), computed
    without packing: a 3 x 3 kernel over 2 x 2 cells is a 6 x 6 kernel of stride 2 over the full-resolution planes
    (padding 2 for the cells' padding 1), so the mosaic and the base are read as one 4-channel image (in the
    channels-last layout if asked) and the noise planes, constant, by their own half-resolution product (the
    convolution is linear in its input channels). The same sums in another order (1e-7 relative) at a third of the
    packed path's CPU time; (B, C, H/2, W/2).

    With ``fold_raw`` (inference, where nothing differentiates the weights), the mosaic's taps are added to the
    base's taps of the colour each samples, and only the base is read (a quarter fewer multiply-adds): the same sums
    wherever the base keeps every mosaic sample exactly, as each of :data:`BASES` does on an RGGB mosaic
    (``tests/isp/test_learned_family.py``)."""
    b, _, hh, ww = raw.shape
    c_out = conv.weight.shape[0]
    # weight[:, 4 i + 2 dy + dx, ky, kx] -> full-resolution tap (2 ky + dy, 2 kx + dx) of input plane i
    w = conv.weight[:, :16].reshape(c_out, 4, 2, 2, 3, 3).permute(0, 1, 4, 2, 5, 3).reshape(c_out, 4, 6, 6)
    layout = torch.channels_last if channels_last else torch.contiguous_format
    if fold_raw:
        # tap (a, b) reads a pixel of row parity a % 2 and column parity b % 2 (the padding, 2, is even): on RGGB
        # that is R, G, G, B for parities (0, 0), (0, 1), (1, 0), (1, 1); plane 1 + c of the input is colour c
        w = w[:, 1:].clone()
        for dy, dx, c in ((0, 0, 0), (0, 1, 1), (1, 0, 1), (1, 1, 2)):
            w[:, c, dy::2, dx::2] += conv.weight[:, 2 * dy + dx].reshape(c_out, 3, 3)  # (input plane 0: the mosaic)
        y = F.conv2d(base.contiguous(memory_format=layout), w, conv.bias, stride=2, padding=2)
    else:
        x = torch.empty(b, 4, hh, ww, dtype=raw.dtype, device=raw.device, memory_format=layout)
        x[:, :1] = raw
        x[:, 1:] = base
        y = F.conv2d(x, w, conv.bias, stride=2, padding=2)
    if noise is not None and noise.shape[1]:
        planes = noise[:, :, None, None].expand(-1, -1, hh // 2, ww // 2).to(y.dtype)
        y = y.add_(F.conv2d(planes, conv.weight[:, 16:].to(y.dtype), None, padding=1))  # (keeps y's layout)
    return y


def _head_forward(head: nn.Conv2d, x: torch.Tensor, scale: float = 1.0) -> tuple[torch.Tensor, list[int] | None]:
    """``scale * head(x)`` (the scale folded into the weights) for inference, and which of the head's output
    channels the result holds: only those with a nonzero weight or bias are computed (None: all). A noise-free
    network's head has exact zeros for the four corrections at the mosaic's own samples (each 2 x 2 cell's R, two
    G and B, which the noise-free networks' heads never change; the guard's high-pass then moves them, see
    :func:`guard_residual`), so it computes 8 of 12. On CPU the count is rounded up to
    a multiple of 8 with zero weights (the extra channels dropped, a view): oneDNN runs such counts faster (16 -> 12
    channels, 3 x 3, 2 threads, AVX2: 10.5 ms/MP; as 16: 7.8; 8: 5.2). The same values as ``head(x)``, the
    channels not computed being exact zeros there."""
    weight, bias = (head.weight * scale, head.bias * scale) if scale != 1.0 else (head.weight, head.bias)
    used = (weight.flatten(1).ne(0).any(1) | bias.ne(0)).nonzero().flatten().tolist()
    keep = None if len(used) == weight.shape[0] else used
    if keep == []:  # a zero correction (an untrained head, or scale 0)
        return x.new_zeros(x.shape[0], 0, *x.shape[2:]), keep
    if keep is not None:
        weight, bias = weight[keep], bias[keep]
    pad = -weight.shape[0] % 8 if x.device.type == "cpu" else 0
    if pad:
        weight = torch.cat([weight, weight.new_zeros(pad, *weight.shape[1:])])
        bias = torch.cat([bias, bias.new_zeros(pad)])
    y = head._conv_forward(x, weight, bias)
    return (y[:, :y.shape[1] - pad] if pad else y), keep


def _unpack(y: torch.Tensor, add_to: torch.Tensor | None = None, channels: list[int] | None = None) -> torch.Tensor:
    """``pixel_shuffle(y, 2)`` in one copy whatever ``y``'s memory layout, into a fresh tensor (which callers may
    write over): (B, 4C, h, w) -> (B, C, 2h, 2w). With ``add_to`` (B, C, 2h, 2w), contiguous: added to it in place
    instead (``add_to += pixel_shuffle(y, 2)`` in one pass), which is returned. With ``channels`` (from
    :func:`_head_forward`): ``y``'s channels are those of the full 4C, the others zero."""
    if channels is not None:
        b, _, h, w = y.shape
        c = 3 if add_to is None else add_to.shape[1]
        out = y.new_zeros(b, c, 2 * h, 2 * w) if add_to is None else add_to
        cells = out.view(b, c, h, 2, w, 2)
        for k, ch in enumerate(channels):  # channel 4 c + 2 dy + dx: colour c at (dy, dx) of each cell
            cells[:, ch // 4, :, ch % 4 // 2, :, ch % 2].add_(y[:, k])
        return out
    b, c4, h, w = y.shape
    cells = y.view(b, c4 // 4, 2, 2, h, w).permute(0, 1, 4, 2, 5, 3)
    if add_to is not None:
        add_to.view(b, c4 // 4, h, 2, w, 2).add_(cells)
        return add_to
    out = torch.empty(b, c4 // 4, 2 * h, 2 * w, dtype=y.dtype, device=y.device)
    out.view(b, c4 // 4, h, 2, w, 2).copy_(cells)
    return out


class _ResidualBlock(nn.Module):
    """``x + conv2(relu(conv1(x)))`` (3x3, same width; He et al. 2016, no batch norm as in EDSR)."""

    def __init__(self, channels: int):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.relu(self.conv1(x)))


def noise_features(shot_gain, read_var) -> torch.Tensor:
    """The joint network's noise inputs ``[sqrt(a) * 10, sqrt(b) * 100]`` for a mosaic with variance ``a x + b``
    (Poisson-Gaussian, Foi et al. IEEE TIP 2008; the scales bring typical values to ~1). ``shot_gain`` and
    ``read_var``: scalars or ``[B]`` tensors (finite, >= 0); returns ``[B, 2]`` (``[1, 2]`` for scalars)."""
    a = torch.as_tensor(shot_gain, dtype=torch.float64).reshape(-1)
    b = torch.as_tensor(read_var, dtype=torch.float64).reshape(-1)
    for name, t in (("shot_gain", a), ("read_var", b)):  # an inf or NaN level would make every output NaN
        if not bool(torch.isfinite(t).all()):
            raise ValueError(f"{name}: expected finite noise parameters, found {int((~torch.isfinite(t)).sum())} "
                             f"NaN/inf of {t.numel()}")
    if not (bool((a >= 0).all()) and bool((b >= 0).all())):
        raise ValueError(f"shot_gain, read_var: expected values >= 0, got {a.tolist()}, {b.tolist()}")
    a, b = torch.broadcast_tensors(a, b)
    # (d sqrt / dt at 0 was inf: NaN through the network at a or b = 0)
    return torch.stack([safe_sqrt(a) * 10.0, safe_sqrt(b) * 100.0], 1)


def noise_parameters(features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(a [B], b [B])`` of :func:`noise_features`' ``[B, 2]`` output (its inverse)."""
    return (features[:, 0] / 10.0) ** 2, (features[:, 1] / 100.0) ** 2


def mosaic_noise_sigma(raw: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """The noise standard deviation ``[B]`` of a mosaic ``raw`` ``[B, 1, H, W]`` at its mean level:
    ``sqrt(b + a mean(raw))`` for the noise inputs ``noise`` (:func:`noise_features`, variance ``a x + b``); float64.
    The level both gates of :data:`PRETRAINED_GATES` are functions of."""
    return _noise_at_mean(raw, noise)[0]


def _noise_at_mean(raw: torch.Tensor, noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(sigma, m)`` ``[B]`` float64: the noise at the mosaic's mean level and that level ``m``."""
    a, b = noise_parameters(noise.to(torch.float64))
    level = raw.detach().to(torch.float64).clamp_min(0).mean((1, 2, 3))
    # (sqrt at 0 gave the noise features NaN gradients at noise 0; the clamp alone left sigma 1.5e-154 at noise 0,
    # which switched the high-noise gate's classical expert on for a float64 mosaic: "'nlmeans' needs a noise level")
    var = b + a * level
    sigma = var.clamp_min(torch.finfo(torch.float64).tiny).sqrt()
    return torch.where(var > 0, sigma, torch.zeros_like(sigma)), level


def level_gate_weight(raw: torch.Tensor, noise: torch.Tensor, sigma_max: float | None = None, *,
                      relative_max: float | None = None) -> torch.Tensor:
    """The low-noise gate's weight ``[B]`` of the expert (:data:`PRETRAINED_GATES`): ``clamp(1 - sigma / sigma_max,
    0, 1)`` with ``sigma`` = :func:`mosaic_noise_sigma` (1 for a noise-free mosaic, 0 from ``sigma_max`` on); or,
    with ``relative_max`` instead, of the noise against the signal: ``clamp(1 - r / relative_max, 0, 1)`` with
    ``r = sigma / mean(raw)`` (the same for a frame and the frame scaled, with its noise, by any exposure)."""
    if (sigma_max is None) == (relative_max is None):
        raise ValueError(f"sigma_max, relative_max: expected exactly one, got {sigma_max}, {relative_max}")
    sigma, level = _noise_at_mean(raw, noise)
    if sigma_max is not None:
        return (1 - sigma / sigma_max).clamp(0, 1)
    return (1 - sigma / level.clamp_min(1e-6) / relative_max).clamp(0, 1)


def _level_gate(raw: torch.Tensor, noise: torch.Tensor, gate: dict) -> torch.Tensor:
    """The low-noise gate of a shipped gate dict (its ``sigma_max`` or its ``relative_max``)."""
    return level_gate_weight(raw, noise, gate.get("sigma_max"), relative_max=gate.get("relative_max"))


def _check_ramp(sigma_start, sigma_full, weight_max) -> None:
    if not (all(isinstance(v, (int, float)) and math.isfinite(v) for v in (sigma_start, sigma_full, weight_max))
            and 0 <= sigma_start < sigma_full and 0 < weight_max <= 1):
        raise ValueError(f"sigma_start, sigma_full, weight_max: expected finite numbers with 0 <= sigma_start < "
                         f"sigma_full and 0 < weight_max <= 1, got {sigma_start!r}, {sigma_full!r}, {weight_max!r}")


def _check_detail(weight_max, weight_detail, detail_r, window) -> tuple[float, float]:
    try:
        r0, r1 = (float(v) for v in detail_r)
    except (TypeError, ValueError):
        raise ValueError(f"detail_r: expected two numbers (r0, r1), got {detail_r!r}") from None
    if not (math.isfinite(r0) and math.isfinite(r1) and 0 <= r0 < r1 and isinstance(weight_detail, (int, float))
            and 0 <= weight_detail <= 1 and isinstance(weight_max, (int, float)) and 0 < weight_max <= 1):
        raise ValueError(f"detail_r, weight_detail, weight_max: expected finite 0 <= r0 < r1, 0 <= weight_detail <= 1 "
                         f"and 0 < weight_max <= 1, got {detail_r!r}, {weight_detail!r}, {weight_max!r}")
    if isinstance(window, bool) or not isinstance(window, int) or window < 1 or window % 2 == 0:
        raise ValueError(f"window: expected an odd number of pixels >= 1 (a centred box), got {window!r}")
    return r0, r1


_CLASSICAL_KEYS = ("sigma_start", "sigma_full", "weight_max", "denoiser", "method")
_CLASSICAL_DETAIL_KEYS = ("weight_detail", "detail_r")
#: the box (pixels, odd) over which :func:`classical_detail_weight` measures local contrast; the shipped gate's
#: ``detail_r`` was chosen with it (``docs/training_log.md#classical_detail_gate_2026-11-30``)
DETAIL_WINDOW = 5


def check_classical_gate(classical: dict, name: str = "classical") -> dict:
    """``classical`` (a joint network's high-noise gate, :data:`PRETRAINED_GATES`) if it holds ``sigma_start``,
    ``sigma_full``, ``weight_max``, ``denoiser`` and ``method`` with valid values, and either both or neither of
    ``weight_detail`` and ``detail_r`` (the per-pixel weighting); else a ValueError naming ``name`` and the key.
    Checked on every call, whether or not the gate is on for the images given."""
    if not isinstance(classical, dict):
        raise TypeError(f"{name}: expected a dict, got {type(classical).__name__}")
    keys = set(classical)
    missing = [k for k in _CLASSICAL_KEYS if k not in keys]
    unknown = sorted(keys - set(_CLASSICAL_KEYS) - set(_CLASSICAL_DETAIL_KEYS))
    if missing or unknown:
        raise ValueError(f"{name}: expected the keys {list(_CLASSICAL_KEYS)} (and optionally both of "
                         f"{list(_CLASSICAL_DETAIL_KEYS)}); missing {missing}, unknown {unknown}")
    if ("weight_detail" in keys) != ("detail_r" in keys):
        raise ValueError(f"{name}: 'weight_detail' and 'detail_r' go together (the per-pixel weighting); got only "
                         f"{'weight_detail' if 'weight_detail' in keys else 'detail_r'!r}")
    _check_ramp(classical["sigma_start"], classical["sigma_full"], classical["weight_max"])
    if "detail_r" in keys:
        _check_detail(classical["weight_max"], classical["weight_detail"], classical["detail_r"], DETAIL_WINDOW)
    return classical


def classical_gate_weight(raw: torch.Tensor, noise: torch.Tensor, sigma_start: float, sigma_full: float,
                          weight_max: float) -> torch.Tensor:
    """``weight_max`` times the high-noise gate's level ramp ``[B]`` (:data:`PRETRAINED_GATES`): 0 up to a noise
    ``sigma`` (:func:`mosaic_noise_sigma`) of ``sigma_start``, rising linearly to ``weight_max`` at ``sigma_full`` and
    constant beyond. Without ``detail_r`` it is the classical expert's weight for the whole image; with it, the
    per-pixel weight is the ramp times :func:`classical_detail_weight`."""
    _check_ramp(sigma_start, sigma_full, weight_max)
    ramp = (mosaic_noise_sigma(raw, noise) - sigma_start) / (sigma_full - sigma_start)
    return weight_max * ramp.clamp(0, 1)


def classical_detail_weight(image: torch.Tensor, noise: torch.Tensor, weight_max: float, weight_detail: float,
                            detail_r: tuple[float, float], window: int = DETAIL_WINDOW) -> torch.Tensor:
    """The high-noise gate's weight factor per pixel ``[B, 1, H, W]`` (:data:`PRETRAINED_GATES`, ``detail_r``):
    ``weight_max`` where an estimate ``image`` ``[B, 3, H, W]`` is flat within its noise, ``weight_detail`` where it
    has detail, linear in between (either may be the larger). The detail is the local contrast against the local
    noise, ``r = std(L) / sqrt(b + a max(mean(L), 0))`` over ``window`` x ``window`` pixels (odd; replicate border) of
    the luminance ``L`` (the mean of the channels) for the noise inputs ``noise`` ``[B, 2]`` or ``[1, 2]``
    (:func:`noise_features`, variance ``a x + b``); where that noise is 0 (no noise, or shot noise alone on a black
    region) ``r`` is infinite, so the factor is ``weight_detail``. The factor is ``weight_detail + (weight_max -
    weight_detail) clamp((r1 - r) / (r1 - r0), 0, 1)`` for ``detail_r = (r0, r1)``.
    Why (``docs/training_log.md#classical_detail_gate_2026-11-30``): on photographs a 13 x 13 non-local search (the
    classical expert) denoises flat regions better than the joint network, and the network keeps texture better.
    The map is a function of ``image`` and the noise inputs only (no gradient through it: a gate, not a loss); in
    ``image``'s dtype."""
    r0, r1 = _check_detail(weight_max, weight_detail, detail_r, window)
    lum = image.detach().to(torch.float64).mean(1, keepdim=True)
    mean = _box(lum, window)
    std = (_box(lum * lum, window) - mean * mean).clamp_min(0).sqrt()
    a, b = noise_parameters(noise.to(torch.float64).expand(image.shape[0], -1))
    sigma = (b.reshape(-1, 1, 1, 1) + a.reshape(-1, 1, 1, 1) * mean.clamp_min(0)).sqrt()
    r = torch.where(sigma > 0, std / sigma.clamp_min(torch.finfo(torch.float64).tiny), torch.inf)
    flat = ((r1 - r) / (r1 - r0)).clamp(0, 1)
    return (weight_detail + (weight_max - weight_detail) * flat).to(image.dtype)


def classical_expert(raw: torch.Tensor, noise: torch.Tensor, denoiser: str = "nlmeans",
                     method: str = "menon2007", pattern: str = "RGGB") -> torch.Tensor:
    """The high-noise gate's classical expert: each mosaic of ``raw`` ``[B, 1, H, W]`` denoised for its noise
    ``noise`` ``[B, 2]`` (:func:`noise_features`) by :func:`isettorch.isp.denoise.denoise_mosaic` (on the CPU,
    with scikit-image), then demosaicked by ``method``; ``(B, 3, H, W)`` in ``raw``'s dtype and device."""
    from .demosaicing import demosaic
    from .denoise import denoise_mosaic

    a, b = noise_parameters(noise.to(torch.float64).expand(raw.shape[0], -1))
    return torch.cat([demosaic(denoise_mosaic(raw[i:i + 1], denoiser, float(b[i].sqrt()), float(a[i])), pattern,
                               method) for i in range(raw.shape[0])])


SELF_ENSEMBLES = (False, True, "transpose", "dihedral")
# flipped dims of an even-sized RGGB mosaic -> the Bayer pattern it then has
_FLIPS = {(): "RGGB", (-1,): "GRBG", (-2,): "GBRG", (-2, -1): "BGGR"}


def check_self_ensemble(value, name: str = "self_ensemble") -> bool | str:
    """``value`` if it is one of :data:`SELF_ENSEMBLES` (a bool or a name, not 0 or 1), else a ValueError naming
    ``name``."""
    if value not in SELF_ENSEMBLES or not isinstance(value, (bool, str)):
        raise ValueError(f"{name}: expected one of {SELF_ENSEMBLES}, got {value!r}")
    return value


def demosaic_learned(raw: torch.Tensor, pattern: str = "RGGB", *, model: DemosaicNet | None = None,
                     noise: torch.Tensor | None = None, self_ensemble: bool | str = False,
                     variant: str = "noise_free") -> torch.Tensor:
    """Demosaic a Bayer mosaic with a :class:`DemosaicNet` (default: the shipped checkpoint).

    Args:
        raw: ``(B, 1, H, W)`` mosaic, values relative to white = 1 (as the network was trained); any height and
            width of at least 4 (an odd one is completed to whole Bayer cells by reflection, then cropped back).
        pattern: Bayer pattern, one of ``RGGB``, ``BGGR``, ``GRBG``, ``GBRG``.
        model: a network; ``None`` loads :func:`load_pretrained` ``(variant)`` (cached).
        noise: ``(B, noise_inputs)`` noise parameters for a joint denoise+demosaic network (``(1,
            noise_inputs)``: the same for every item; None: a noise-free mosaic's, ``noise_features(0, 0)``). The
            joint model's classical expert (nlmeans, then Menon) is not differentiable: where its gate weighs it
            in (from sigma 0.01 on, flat regions), the output's gradient is the network's share only.
        self_ensemble: average the network on the mosaic and on its transpose (transposed back): an RGGB
            mosaic transposes to an RGGB mosaic, so both passes are valid inputs (geometric self-ensemble:
            Timofte, Rothe & Van Gool, CVPR 2016; Lim et al., EDSR+, CVPRW 2017). Two network passes; the result
            is exactly transpose-equivariant. Default False (one pass). ``"transpose"`` is the same as True.
            ``"dihedral"``: the eight symmetries of the square (Lim et al.'s x8 ensemble): the mosaic flipped
            horizontally is a GRBG mosaic, vertically GBRG, both BGGR, so each flip is demosaicked as its own
            pattern with the transpose ensemble and flipped back, and the eight outputs averaged; eight passes.
            Exactly transpose-equivariant; flip-equivariant away from the borders (a flipped input is another
            Bayer pattern, so it gets the one-pixel pad).
        variant: the shipped network used when ``model`` is None (:data:`PRETRAINED`).

    Returns:
        ``(B, 3, H, W)`` RGB (not clipped).
    """
    checked = _check_raw(raw, even=False)  # [B, 1, H, W] (one [H, W] mosaic is a batch of 1)
    check_finite(checked, "raw")  # (a NaN sample would spread over the whole image through the guard's local means)
    _check_noise_features(noise, checked.shape[0])  # (the batch: an [H, W] mosaic's H had been taken for it)
    return _demosaic_learned(raw, pattern, model=model, noise=noise, self_ensemble=self_ensemble, variant=variant)


def _check_noise_features(noise, batch: int) -> None:
    """A joint network's noise features, once per call at the entry points (not per flip of the dihedral ensemble:
    two host reads): None or a floating-point tensor ``[B, k]`` or ``[1, k]`` for a batch of ``batch``
    mosaics, of finite values >= 0 (NaN gave an all-NaN image; a ``[3, 2]`` for two mosaics was reported as the
    ``(2, 3)`` it was reshaped to, a ``[4]`` failed with an IndexError after the network had run)."""
    if noise is None:
        return
    if not isinstance(noise, torch.Tensor) or not noise.is_floating_point():
        raise TypeError(f"noise: expected a floating-point tensor (B, noise_inputs), got "
                        f"{noise.dtype if isinstance(noise, torch.Tensor) else type(noise).__name__}")
    if noise.dim() != 2 or noise.shape[0] not in (1, batch):
        raise ValueError(f"noise: expected shape [B, noise_inputs] (or [1, noise_inputs]) for {batch} mosaic(s), got "
                         f"{tuple(noise.shape)}")
    check_finite(noise, "noise")
    if bool((noise < 0).any()):
        raise ValueError(f"noise: expected non-negative noise parameters [sqrt(a) * 10, sqrt(b) * 100], got "
                         f"{noise.detach().reshape(-1)[:6].tolist()}")
    if noise.shape[-1] == 2:
        # a noise standard deviation at white, sqrt(a + b), above the [0, 1] mosaic's full scale is no camera's
        # (the joint model trained to a = 0.0128 and sigma = 0.08): the shipped network's output grew with it, and
        # from a = 100 its gate let the result through (-23.5..10.4 for a [0.4, 0.5] image) with no word
        a, b = noise_parameters(noise.detach().to(torch.float64))
        if bool((a + b > 1.0).any()):
            raise ValueError(f"noise: expected a noise level within the mosaic's full scale, a + b <= 1 (sqrt(a + b) "
                             f"the noise std at white), got a = {a.reshape(-1)[:4].tolist()}, b = "
                             f"{b.reshape(-1)[:4].tolist()} (features [sqrt(a) * 10, sqrt(b) * 100])")


def _demosaic_learned(raw, pattern, *, model, noise, self_ensemble, variant) -> torch.Tensor:
    """:func:`demosaic_learned` on a mosaic whose values were checked finite by the caller (its public entry, or
    :func:`isettorch.isp.demosaicing.demosaic` for the registered methods): one pass over the input, not one per
    entry and per flip of the dihedral ensemble."""
    raw = _check_raw(raw, even=False)
    pattern = check_bayer_pattern(pattern)
    check_self_ensemble(self_ensemble)
    if model is None:  # the shared cached instance (load_pretrained gives callers their own copy)
        model = _pretrained(_check_variant(variant), str(raw.device), raw.dtype, True)
    elif isinstance(model, nn.Module):  # (torch's "Input type (double) and bias type (float)" named neither)
        param = next(model.parameters(), None)
        if param is not None and param.dtype != raw.dtype:
            raise ValueError(f"model: its weights are {param.dtype}, the mosaic raw is {raw.dtype}; convert one "
                             f"(model.to({raw.dtype}), or load_pretrained(..., dtype={raw.dtype}))")
    if raw.shape[0] == 0:  # an empty batch: no network pass
        return raw.new_zeros((0, 3, *raw.shape[-2:]))
    n_in = getattr(model, "noise_inputs", 0)
    if n_in and noise is None:  # a joint network without noise features: those of a noise-free mosaic, and its
        # gates (the network alone read zeros but skipped the gates: up to 0.26 off the noise-free answer)
        noise = torch.zeros(raw.shape[0], n_in, dtype=raw.dtype, device=raw.device)
    elif n_in and noise.dim() == 2 and noise.shape[0] == 1 and raw.shape[0] > 1:  # one set for the batch
        noise = noise.expand(raw.shape[0], -1)  # (noise_features of two numbers is [1, 2]: a batch raised)
    x, dy, dx = _to_rggb(raw, pattern)
    if x.shape[-2] % 2 or x.shape[-1] % 2:
        # an odd height or width: one more row / column, the reflection of the one before the last (the same
        # colours: the Bayer pattern has period 2), so the network sees whole cells; cropped off below
        x = F.pad(x, (0, x.shape[-1] % 2, 0, x.shape[-2] % 2), mode="reflect")
    def run(net, nz):
        if self_ensemble == "dihedral":
            return torch.stack([_demosaic_learned(x.flip(dims), flipped, model=net, noise=nz,
                                                  self_ensemble=True, variant=variant).flip(dims)
                                for dims, flipped in _FLIPS.items()]).mean(0)
        y = net(x, nz)
        if self_ensemble:
            y = 0.5 * (y + net(x.transpose(-1, -2), nz).transpose(-1, -2))
        return y

    out = run(model, noise)
    gate = getattr(model, "level_gate", None)
    if gate is not None and noise is not None and self_ensemble != "dihedral":  # (dihedral: the gates are inside)
        w = _level_gate(raw, noise, gate).to(out.dtype)
        if bool((w > 0).any()):  # the expert runs only where it is weighed in
            w = w.reshape(-1, 1, 1, 1)
            out = w * run(gate["expert"], None) + (1 - w) * out
        classical = gate.get("classical")
        if classical is not None:
            check_classical_gate(classical, "model.level_gate['classical']")
            ramp = classical_gate_weight(raw, noise, classical["sigma_start"], classical["sigma_full"],
                                         1.0).to(out.dtype)
            on = torch.nonzero(ramp > 0).flatten()
            if on.numel():  # the classical expert runs only on the images it is weighed in for
                nz = noise.expand(x.shape[0], -1)[on]
                expert = classical_expert(x[on], nz, classical["denoiser"], classical["method"]).to(out.dtype)
                wo = ramp[on].reshape(-1, 1, 1, 1) * (  # per pixel (weight_max where flat), or weight_max
                    classical_detail_weight(0.5 * (expert + out[on]), nz, classical["weight_max"],
                                            classical["weight_detail"], classical["detail_r"])
                    if "detail_r" in classical else classical["weight_max"])
                out = out.index_copy(0, on, wo * expert + (1 - wo) * out[on])
    return out[..., dy:dy + raw.shape[-2], dx:dx + raw.shape[-1]]


def load_checkpoint(path: str | Path, *, device=None, dtype=None) -> tuple[DemosaicNet, dict]:
    """Load a checkpoint written by ``training/train_demosaic.py`` (``torch.load(weights_only=True)``).

    Returns the network (in eval mode) and the checkpoint's metadata dict.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no checkpoint at {path}")
    check_zip_crc(path, "path")
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(ckpt, dict) or "model" not in ckpt or "net_config" not in ckpt:
        raise ValueError(f"path: {path} is not a DemosaicNet checkpoint (expected keys 'model' and 'net_config')")
    with torch.random.fork_rng(devices=[]):  # the initial weights, replaced by the checkpoint's, drew from the
        net = DemosaicNet(**ckpt["net_config"])  # global generator (a first evaluate_demosaic moved a run's draws)
    net.load_state_dict(ckpt["model"])
    net.eval().requires_grad_(False)
    if device is not None or dtype is not None:
        net.to(device=device, dtype=dtype)
    return net, {k: v for k, v in ckpt.items() if k not in ("model", "optimizer")}


def apply_shipped_settings(net: DemosaicNet, variant: str) -> DemosaicNet:
    """Set on ``net`` (in place; returned) what shipped ``variant`` runs with around its weights: its guard
    (:data:`PRETRAINED_GUARDS`), correction scale (:data:`PRETRAINED_CORRECTION_SCALES`) and classical blend
    (:data:`PRETRAINED_BLENDS`), whatever ``net``'s checkpoint recorded. The joint network's gates are not set here
    (:func:`load_pretrained`)."""
    variant = _check_variant(variant)
    net.guard = dict(PRETRAINED_GUARDS[variant])
    net.correction_scale = float(PRETRAINED_CORRECTION_SCALES.get(variant, 1.0))
    net.blend = dict(PRETRAINED_BLENDS[variant]) if variant in PRETRAINED_BLENDS else None
    return net


@tensor_cache(maxsize=8)
def _pretrained(variant: str, device: str, dtype: torch.dtype, guard: bool = True) -> DemosaicNet:
    net = load_checkpoint(PRETRAINED[variant], device=device, dtype=dtype)[0]
    if guard:
        apply_shipped_settings(net, variant)
    else:
        net.guard, net.correction_scale, net.blend = None, 1.0, None
    gate = PRETRAINED_GATES.get(variant)
    # the low-noise gate (demosaic_learned): the shipped expert under its own guard; none for the bare network
    net.level_gate = None if gate is None or not guard else {
        "expert": _pretrained(gate["expert"], device, dtype, True),
        **{k: (dict(v) if isinstance(v, dict) else float(v)) for k, v in gate.items() if k != "expert"}}
    return net


def _check_variant(variant: str) -> str:
    if variant not in PRETRAINED:
        raise ValueError(f"variant: expected one of {sorted(PRETRAINED)}, got {variant!r}")
    return variant


def load_pretrained(variant: str = "noise_free", *, device=None, dtype=torch.float32, guard: bool = True
                    ) -> DemosaicNet:
    """A shipped :class:`DemosaicNet` (``isettorch/assets``), eval mode, frozen, with its guard
    (:data:`PRETRAINED_GUARDS`, :func:`guard_residual`) and, for the joint network, its low-noise gate
    (:data:`PRETRAINED_GATES`, applied by :func:`demosaic_learned`), correction scale
    (:data:`PRETRAINED_CORRECTION_SCALES`) and classical blend (:data:`PRETRAINED_BLENDS`); ``guard=False``: the bare
    network (scale 1, no blend), for comparisons.
    Each call returns its own copy of a cached network (a few ms), so changing its guard, scale, weights, dtype or
    ``requires_grad`` changes neither later calls nor the registered ``learned*`` methods.

    ``variant="noise_free"`` (``demosaic_learned.pt``) or ``"joint_denoise"`` (``demosaic_learned_denoise.pt``,
    which takes ``noise = [sqrt(a) * 10, sqrt(b) * 100]`` for a mosaic with variance ``a x + b``; see
    ``training/train_demosaic.py``). The joint network is a residual 64 x 13 network trained by
    ``configs/train/demosaic_joint_all_levels.yaml`` then ``demosaic_joint_guarded.yaml`` (its guard in the loop) on
    :mod:`isettorch.data.natural` scenes through the Camera (white-balanced linear sRGB targets, 80 % of patches
    display-encoded; the sensor model's noise: shot, read, dark, DSNU/PRNU, quantisation, with ``a``, ``b`` in the
    [0, 1] units of the mosaic, white Gaussian noise, ``a = 0``, and an eighth of each batch noise-free), starting
    from the shipped noise-free network. The noise-free network is the same residual
    64 x 13, trained from :mod:`isettorch.data.natural` scenes only in three stages:
    ``demosaic_noise_free.yaml`` (generator version 4), ``demosaic_noise_free_finetune.yaml`` (version 5, with
    chromatic detail and independent three-layer grain), then ``demosaic_noise_free_stage3.yaml`` (version 5, a
    fresh scene bank, lower learning rate). ``"tiny"`` and ``"small"`` (methods ``learned_tiny``, ``learned_small``)
    are a plain 16 x 3 network on Menon et al. 2007 without its refining step (``base="menon2007_norefine"``) and a
    residual 24 x 5 network on Menon et al. 2007 (``base="menon2007"``), trained from scratch by
    ``configs/train/demosaic_tiny.yaml`` / ``demosaic_small.yaml``; the tiny one then distilled from the noise-free
    network on the full Menon base (``demosaic_tiny_distill.yaml``) and again on the unrefined one
    (``demosaic_tiny_norefine.yaml``). Each JSON beside a checkpoint
    records its command, config,
    steps, wall time, hardware and scores; the model cards (``.md``) add held-out synthetic screens.

    Example:
        >>> net = load_pretrained()
        >>> net(torch.rand(1, 1, 32, 32)).shape
        torch.Size([1, 3, 32, 32])
    """
    return copy.deepcopy(_pretrained(_check_variant(variant), str(torch.device(device or "cpu")), dtype,
                                     check_bool(guard, "guard")))


def pretrained_info(variant: str = "noise_free") -> dict:
    """The training record shipped beside a checkpoint (command, config, data, wall time, hardware, scores)."""
    p = PRETRAINED[_check_variant(variant)].with_suffix(".json")
    return json.loads(p.read_text()) if p.is_file() else {}


def _register() -> None:
    import importlib

    try:
        _dm = importlib.import_module(__name__.rsplit(".", 1)[0] + ".demosaicing")
    except ImportError:  # the demosaic module is optional for this file
        return
    reg = getattr(_dm, "register_method", None)
    if reg is None:
        return

    for name, variant in LEARNED_METHODS.items():
        def _learned(raw, pattern="RGGB", *, _variant=variant, model=None, noise=None, self_ensemble=False):
            # reached through demosaic(), which has checked the values finite
            _check_noise_features(noise, raw.shape[0] if isinstance(raw, torch.Tensor) and raw.dim() == 4 else 1)
            return _demosaic_learned(raw, pattern, model=model, noise=noise, self_ensemble=self_ensemble,
                                     variant=_variant)

        try:
            reg(name, _learned)
        except (ValueError, KeyError):  # already registered (module re-import)
            pass


_register()
