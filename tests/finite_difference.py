"""Central differences of a loss in one parameter, for tests that check autograd against them."""

from __future__ import annotations

import torch


def central_difference(loss, param: torch.Tensor, h: float) -> float:
    """``(loss() at param + h - loss() at param - h) / (2 h)``: ``param`` (a tensor, e.g. a learnable f-number) is
    moved in place and restored, without recording gradients; ``loss`` takes no arguments."""
    with torch.no_grad():
        param.add_(h)
        up = float(loss())
        param.sub_(2 * h)
        down = float(loss())
        param.add_(h)
    return (up - down) / (2 * h)
