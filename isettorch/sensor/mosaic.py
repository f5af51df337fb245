"""A learnable P x Q colour filter mosaic: each pixel of the unit cell chooses one filter of a bank.

The choice is relaxed while training: pixel ``(p, q)`` of the cell reads ``sum_k w_k(p, q) rate_k`` with
``w(p, q) = softmax(logits(p, q) / temperature)`` over the K filters, and the temperature falls during training
(:func:`temperature_schedule`) so the weights become one-hot. In eval mode (and in the exported design) the mosaic
is hard: one filter per pixel, the argmax, as a sensor is built. ``relax='straight_through'`` reads the hard mosaic
in the forward pass and passes the softmax's gradient (Bengio, Leonard & Courville 2013), so a network can be
trained on the mosaic the sensor will have while the choice still learns.

:class:`LearnedMosaic` is a :class:`~isettorch.sensor.cfa.CFA` (its ``cell``, ``index_map``, ``masks`` are the hard
argmax pattern) and an ``nn.Module`` (the logits are parameters of the :class:`~isettorch.sensor.Sensor` that holds
it): the sensor's one ``cfa.mosaic(rates)`` call applies the relaxed choice, so exposure, noise and the ADC are the
sensor's own.

References: Chakrabarti, "Learning sensor multiplexing design through back-propagation", NeurIPS 2016 (a softmax
over the filter choice per mosaic pixel, its scale raised during training); Jang, Gu & Poole, "Categorical
reparameterization with Gumbel-softmax", ICLR 2017 (annealed softmax temperature).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from .._checks import check_seed, is_integer
from .cfa import CFA, tile

__all__ = ["RELAX_MODES", "LearnedMosaic", "temperature_schedule"]

RELAX_MODES = ("softmax", "straight_through")


def temperature_schedule(step: int, total_steps: int, start: float = 1.0, end: float = 0.05) -> float:
    """Geometric annealing ``start (end / start)^(step / total_steps)`` (held at ``end`` after ``total_steps``).

    Example:
        >>> temperature_schedule(0, 100), round(temperature_schedule(50, 100, 1.0, 0.01), 6)
        (1.0, 0.1)
        >>> temperature_schedule(200, 100)
        0.05
    """
    if not (start > 0 and end > 0 and math.isfinite(start) and math.isfinite(end)):
        raise ValueError(f"start, end: expected positive temperatures, got {start!r}, {end!r}")
    if not (isinstance(total_steps, int) and total_steps >= 1):
        raise ValueError(f"total_steps: expected a positive integer, got {total_steps!r}")
    if not (isinstance(step, (int, float)) and math.isfinite(step)):
        raise ValueError(f"step: expected a finite step number, got {step!r}")
    frac = min(max(step / total_steps, 0.0), 1.0)
    return float(start * (end / start) ** frac)


class LearnedMosaic(nn.Module, CFA):
    """A P x Q mosaic over K filters: logits ``[K, P, Q]``, relaxed in training, hard in eval.

    Args:
        channel_names: the K filter names (those of the sensor's :class:`~isettorch.sensor.filter_bank.FilterBank`).
        shape: ``(P, Q)`` of the unit cell (e.g. ``(2, 2)``, ``(4, 4)``, ``(8, 8)``).
        pattern: optional initial hard pattern: a :class:`CFA` or an ``[P, Q]`` index map; with ``learnable=False``
            the mosaic is that fixed pattern (a fixed design expressed in the same module).
        learnable: learn the logits.
        temperature: the softmax temperature (set it every step, e.g. from :func:`temperature_schedule`).
        relax: ``'softmax'`` or ``'straight_through'`` (module docstring).
        init_scale, seed: random initial logits ``init_scale * N(0, 1)`` (without ``pattern``).
        pattern_margin: the initial logits of a ``pattern``: ``pattern_margin`` for each pixel's filter, 0 for the
            others (default 4: softmax weight 0.95 with 4 filters at temperature 1; a smaller margin lets a
            learnable mosaic leave its start more easily).

    Example:
        >>> m = LearnedMosaic(["R", "G", "B", "W"], (4, 4))
        >>> m.eval().weights(4, 4).sum(0).unique().tolist(), m.index_map.shape
        ([1.0], torch.Size([4, 4]))
    """

    def __init__(self, channel_names: Sequence[str], shape: tuple[int, int] = (2, 2), *, pattern=None,
                 learnable: bool = True, temperature: float = 1.0, relax: str = "softmax", init_scale: float = 0.01,
                 seed: int = 0, pattern_margin: float = 4.0) -> None:
        nn.Module.__init__(self)
        names = [str(n) for n in channel_names]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"channel_names: expected unique filter names, got {names}")
        if pattern is not None:
            if isinstance(pattern, CFA):
                lookup = {n: i for i, n in enumerate(names)}
                missing = [x for r in pattern.cell for x in r if x not in lookup]
                if missing:
                    raise ValueError(f"pattern: filters {sorted(set(missing))} are not in channel_names {names}")
                index = torch.tensor([[lookup[x] for x in r] for r in pattern.cell], dtype=torch.long)
            else:
                raw = torch.as_tensor(pattern)
                if raw.is_floating_point() and not bool((raw == raw.round()).all()):
                    raise ValueError(f"pattern: expected integer filter indices, got {raw.tolist()}")
                index = raw.to(torch.long)
            if index.dim() != 2 or bool((index < 0).any()) or bool((index >= len(names)).any()):
                raise ValueError(f"pattern: expected a [P, Q] map of filter indices in 0..{len(names) - 1}, got "
                                 f"{index.tolist()}")
            shape = tuple(index.shape)
        if len(shape) != 2 or not all(is_integer(s) and s >= 1 for s in shape):
            raise ValueError(f"shape: expected (P, Q) positive integer sizes, got {shape!r}")
        if relax not in RELAX_MODES:
            raise ValueError(f"relax: expected one of {RELAX_MODES}, got {relax!r}")
        self.channel_names = names
        p, q = int(shape[0]), int(shape[1])
        if pattern is not None:  # one-hot logits of the pattern (margin m: softmax weight e^m / (e^m + K - 1))
            if not (isinstance(pattern_margin, (int, float)) and math.isfinite(pattern_margin) and pattern_margin > 0):
                raise ValueError(f"pattern_margin: expected a positive number, got {pattern_margin!r}")
            logits = float(pattern_margin) * nn.functional.one_hot(index, len(names)).permute(2, 0, 1).to(torch.float64)
        else:
            if not (isinstance(init_scale, (int, float)) and math.isfinite(init_scale) and init_scale >= 0):
                raise ValueError(f"init_scale: expected a finite number >= 0, got {init_scale!r}")
            g = torch.Generator().manual_seed(check_seed(seed))  # (int() took 1.5, True and "3")
            logits = init_scale * torch.randn(len(names), p, q, generator=g, dtype=torch.float64)
        self.logits = nn.Parameter(logits, requires_grad=learnable)
        self.learnable = bool(learnable)  # a flag, not the logits' requires_grad: a fixed mosaic is never relaxed
        self.temperature = float(temperature)
        self.relax = relax

    # --- the CFA view: the hard pattern ---------------------------------------------------------
    @property
    def temperature(self) -> float:
        return self._temperature

    @temperature.setter
    def temperature(self, value: float) -> None:
        # at least 1e-6: the relaxed weights are softmax(logits / T), which overflows for a subnormal T
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 1e-6):
            raise ValueError(f"temperature: expected a number >= 1e-6, got {value!r}")
        self._temperature = float(value)

    @property
    def index_map(self) -> torch.Tensor:
        """``[P, Q]`` long: the filter each pixel of the cell has (the argmax of its logits)."""
        return self.logits.detach().argmax(0).cpu()

    @property
    def cell(self) -> list[list[str]]:
        return [[self.channel_names[int(i)] for i in row] for row in self.index_map]

    @property
    def relaxed(self) -> bool:
        """Whether :meth:`mosaic` mixes filters (training mode of a learnable mosaic)."""
        return self.training and self.learnable

    def _tiled(self, height: int, width: int, device) -> torch.Tensor:
        if height < 1 or width < 1:
            raise ValueError(f"height, width: expected positive sizes, got {height}x{width}")
        return tile(self.index_map.to(device), height, width)  # not cached: the pattern changes as it learns

    def hard_cfa(self) -> CFA:
        """The exported design: a plain :class:`CFA` of the argmax pattern, with the bank's channel order."""
        return CFA(self.cell, channel_names=self.channel_names)

    def fraction(self) -> dict[str, float]:
        """Fraction of the cell's pixels that have each filter (hard pattern)."""
        idx = self.index_map.reshape(-1)
        return {n: float((idx == i).double().mean()) for i, n in enumerate(self.channel_names)}

    # --- relaxed weights ------------------------------------------------------------------------
    def cell_weights(self) -> torch.Tensor:
        """``[K, P, Q]``: the softmax weights (relaxed), one-hot of the argmax (eval or fixed), or the hard weights
        with the softmax's gradient (``straight_through``)."""
        hard = nn.functional.one_hot(self.logits.detach().argmax(0), self.num_channels).permute(2, 0, 1)
        hard = hard.to(self.logits.dtype)
        if not self.relaxed:
            return hard
        soft = torch.softmax(self.logits / self.temperature, dim=0)
        if self.relax == "straight_through":
            return soft + (hard - soft).detach()
        return soft

    def weights(self, height: int, width: int, *, dtype=None, device=None) -> torch.Tensor:
        """Per-pixel filter weights ``[K, H, W]`` (the cell tiled from pixel [0, 0])."""
        if height < 1 or width < 1:
            raise ValueError(f"height, width: expected positive sizes, got {height}x{width}")
        w = self.cell_weights()
        ph, pw = w.shape[-2:]
        reps = (1, -(-height // ph), -(-width // pw))
        out = w.repeat(*reps)[:, :height, :width]
        return out.to(dtype=dtype or out.dtype, device=device or out.device)

    def mosaic(self, channels: torch.Tensor) -> torch.Tensor:
        """Each pixel's signal ``[B, 1, H, W]`` from every filter's ``[B, K, H, W]``: the weighted sum (relaxed) or
        the pixel's own filter (hard: the same gather as :meth:`CFA.mosaic`)."""
        if channels.dim() != 4 or channels.shape[1] != self.num_channels:
            raise ValueError(f"channels: expected shape [B, {self.num_channels}, H, W], got {tuple(channels.shape)}")
        if not self.relaxed:
            return CFA.mosaic(self, channels)
        w = self.weights(channels.shape[2], channels.shape[3], dtype=channels.dtype, device=channels.device)
        return (channels * w[None]).sum(1, keepdim=True)

    # modules compare and hash by identity (a CFA compares by its cell, which changes as the mosaic learns)
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    def __repr__(self) -> str:
        return nn.Module.__repr__(self)

    def extra_repr(self) -> str:
        cell = "/".join(" ".join(r) for r in self.cell)
        return (f"filters={self.channel_names}, shape={tuple(self.logits.shape[1:])}, learnable={self.learnable}, "
                f"temperature={self.temperature:g}, relax={self.relax!r}, cell={cell!r}")
