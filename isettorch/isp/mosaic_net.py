"""A small reconstruction network for any mosaic of K filters: the one network every sensor design is compared with.

Input: the raw mosaic ``[B, 1, H, W]`` (white-normalised: a perfect white reads 1 in every pixel) and the
per-pixel filter weights ``[K, H, W]`` or ``[B, K, H, W]`` (one-hot for a hard mosaic, a softmax while the mosaic
learns). The network sees the mosaic as K sparse channels (``raw x w_k``: each pixel's value in its filter's
channel, zero elsewhere) plus the K weight maps, so it knows the pattern (the "per-filter sparse channel"
input of Chakrabarti, "Learning sensor multiplexing design through back-propagation", NeurIPS 2016, and of Henz,
Gastal & Oliveira, Eurographics 2018), then plain 3x3 convolutions (VGG-style, Simonyan & Zisserman 2015) with
ReLUs, and a 1x1 layer to linear sRGB. The architecture depends on K only through the first layer's input count.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["MosaicReconstructionNet"]


class MosaicReconstructionNet(nn.Module):
    """Mosaic of K filters -> linear sRGB ``[B, 3, H, W]``.

    Args:
        num_filters: K.
        width: feature channels; depth: number of 3x3 convolutions (>= 1).

    Example:
        >>> net = MosaicReconstructionNet(4, width=8, depth=2)
        >>> w = torch.nn.functional.one_hot(torch.randint(0, 4, (8, 8)), 4).permute(2, 0, 1).float()
        >>> net(torch.rand(2, 1, 8, 8), w).shape
        torch.Size([2, 3, 8, 8])
    """

    def __init__(self, num_filters: int, width: int = 32, depth: int = 4) -> None:
        super().__init__()
        for label, v, lo in (("num_filters", num_filters, 1), ("width", width, 1), ("depth", depth, 1)):
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{label}: expected an integer >= {lo}, got {v!r}")
        self.num_filters, self.width, self.depth = num_filters, width, depth
        layers: list[nn.Module] = []
        c = 2 * num_filters
        for _ in range(depth):
            layers += [nn.Conv2d(c, width, 3, padding=1, padding_mode="reflect"), nn.ReLU(inplace=True)]
            c = width
        layers.append(nn.Conv2d(c, 3, 1))
        self.body = nn.Sequential(*layers)

    @property
    def kwargs(self) -> dict:
        """The constructor's arguments (stored in a design file)."""
        return {"num_filters": self.num_filters, "width": self.width, "depth": self.depth}

    def forward(self, raw: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        if raw.dim() != 4 or raw.shape[1] != 1:
            raise ValueError(f"raw: expected a (B, 1, H, W) mosaic, got {tuple(raw.shape)}")
        if weights.dim() == 3:
            weights = weights[None]
        if weights.dim() != 4 or weights.shape[1] != self.num_filters or weights.shape[-2:] != raw.shape[-2:]:
            raise ValueError(f"weights: expected ({self.num_filters}, H, W) or (B, {self.num_filters}, H, W) with "
                             f"H, W = {tuple(raw.shape[-2:])}, got {tuple(weights.shape)}")
        w = weights.to(raw.dtype).expand(raw.shape[0], -1, -1, -1)
        return self.body(torch.cat([raw * w, w], dim=1))
