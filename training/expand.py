"""Collapsible linear expansion of a network's convolutions for training (``expand: M`` in a demosaic config).

Each k x k convolution ``out <- in`` of a :class:`isettorch.isp.learned.DemosaicNet` is trained as a k x k
convolution ``M <- in`` followed by a 1 x 1 convolution ``out <- M`` with nothing between them, plus an identity
shortcut where ``in == out``: a product of linear maps is one linear map, so the pair collapses into one k x k
convolution of the original shape (``weight = W2 W1 + identity``). The forward pass uses the collapsed weight, so a
training step costs what the plain network's does and the trained network, collapsed, is the plain network: the
checkpoint and the shipped architecture (and its CPU time) do not change. What changes is the optimisation: gradient
steps on the factors act on the product as a preconditioned, momentum-like update (Arora, Cohen & Hazan, "On the
optimization of deep networks: implicit acceleration by overparameterization", ICML 2018), which trains small
networks to better optima ("ExpandNets", Guo, Alvarez & Salzmann, NeurIPS 2020; the collapsible linear blocks of
SESR, Bhardwaj et al., MLSys 2022).

The expansion starts at the network's weights exactly: ``W1`` holds the weight (less the identity) in its first
``out`` rows and small random rows below, ``W2`` selects the first ``out`` rows (so ``W2 W1`` is the weight and the
extra rows get gradients through ``W2``'s zero columns).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn.utils import parametrize

__all__ = ["expand_convolutions", "collapsed_state", "is_expanded"]

#: the scale of the extra rows of ``W1`` relative to the weight's RMS
_EXTRA_SCALE = 0.1


class _Collapse(nn.Module):
    """The parametrisation ``weight = W2 @ W1 (+ identity at the centre tap where in == out)``."""

    def __init__(self, weight: torch.Tensor, expand: int, identity: bool):
        super().__init__()
        out_c, in_c, kh, kw = weight.shape
        if expand < out_c:
            raise ValueError(f"expand: expected at least the convolution's {out_c} output channels, got {expand}")
        self.expand = int(expand)
        self.identity = identity and in_c == out_c and kh % 2 == 1 and kw % 2 == 1
        delta = torch.zeros_like(weight)
        if self.identity:
            delta[torch.arange(out_c), torch.arange(out_c), kh // 2, kw // 2] = 1.0
        self.register_buffer("delta", delta, persistent=False)

    def forward(self, w1: torch.Tensor, w2: torch.Tensor) -> torch.Tensor:
        return torch.einsum("om,mikl->oikl", w2, w1) + self.delta

    def right_inverse(self, weight: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out_c = weight.shape[0]
        w = weight - self.delta
        rms = float(w.pow(2).mean().sqrt()) or 1.0
        extra = torch.randn(self.expand - out_c, *w.shape[1:], dtype=w.dtype, device=w.device) * rms * _EXTRA_SCALE
        w1 = torch.cat([w, extra], 0)
        w2 = torch.zeros(out_c, self.expand, dtype=w.dtype, device=w.device)
        w2[:, :out_c] = torch.eye(out_c, dtype=w.dtype, device=w.device)
        return w1, w2


def _convs(net: nn.Module) -> list[nn.Conv2d]:
    return [m for m in net.modules() if isinstance(m, nn.Conv2d)]


def expand_convolutions(net: nn.Module, expand: int) -> nn.Module:
    """Reparametrise every ``Conv2d`` weight of ``net`` in place as a collapsible pair of ``expand`` hidden channels
    (the function ``net`` computes does not change, to float rounding), with the identity shortcut on every
    convolution but the first (whose input channels are the mosaic and the base, not features); returns ``net``."""
    if isinstance(expand, bool) or int(expand) != expand or expand < 1:
        raise ValueError(f"expand: expected an integer number of hidden channels >= 1, got {expand!r}")
    for i, conv in enumerate(_convs(net)):
        parametrize.register_parametrization(conv, "weight", _Collapse(conv.weight.detach(), int(expand), i > 0),
                                             unsafe=True)
    return net


def is_expanded(net: nn.Module) -> bool:
    return any(parametrize.is_parametrized(c, "weight") for c in _convs(net))


def collapsed_state(net: nn.Module) -> dict:
    """``net``'s state dict with each expanded weight collapsed back to one tensor under its plain name (the state
    dict of the plain network computing the same function)."""
    state = {}
    for name, value in net.state_dict().items():
        if ".parametrizations." not in name:
            state[name] = value
    for mod_name, mod in net.named_modules():
        if isinstance(mod, nn.Conv2d) and parametrize.is_parametrized(mod, "weight"):
            state[f"{mod_name}.weight"] = mod.weight.detach().clone()
    return {k: state[k] for k in sorted(state)}
