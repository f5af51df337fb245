"""A small reconstruction network for any mosaic of K filters: the one network every sensor design is compared with.

Input: the raw mosaic ``[B, 1, H, W]`` (white-normalised: a perfect white reads 1 in every pixel) and the
per-pixel filter weights ``[K, H, W]`` or ``[B, K, H, W]`` (one-hot for a hard mosaic, a softmax while the mosaic
learns). The network sees the mosaic as K sparse channels (``raw x w_k``: each pixel's value in its filter's
channel, zero elsewhere) plus the K weight maps, so it knows the pattern (the "per-filter sparse channel"
input of Chakrabarti, "Learning sensor multiplexing design through back-propagation", NeurIPS 2016, and of Henz,
Gastal & Oliveira, Eurographics 2018), then plain 3x3 convolutions (VGG-style, Simonyan & Zisserman 2015) with
ReLUs, and a 1x1 layer to linear sRGB. The architecture depends on K only through the first layer's input count.

Optional context path (``context_scale`` s > 0), for mosaics whose colour samples are sparse or noisy: each
filter's local mean on s x s blocks (normalised convolution, Knutsson & Westin, CVPR 1993: the block sum of
``raw x w_k`` over the block sum of ``w_k``), three 3x3 convolutions at that resolution, bilinear upsampling, and one
3x3 convolution merging it with the local path before the 1x1 layer: a receptive field of about ``7 s`` pixels
instead of ``2 depth + 1`` (the two-path "interpolation + context" structure of Chakrabarti, NeurIPS 2016, section 3).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .._autograd import records_grad
from .._checks import check_finite

__all__ = ["MosaicReconstructionNet"]

#: in inference, images of more pixels than this run in strips of STRIP_ROWS rows (bounded activation memory: a
#: 32-channel activation of a 12 MP photograph is 1.5 GB)
STRIP_PIXELS = 1 << 21
STRIP_ROWS = 256


class MosaicReconstructionNet(nn.Module):
    """Mosaic of K filters -> linear sRGB ``[B, 3, H, W]``.

    Args:
        num_filters: K.
        width: feature channels; depth: number of 3x3 convolutions (>= 1).
        context_scale: block size of the context path (see the module docstring); 0 (default): none.

    Example:
        >>> net = MosaicReconstructionNet(4, width=8, depth=2)
        >>> w = torch.nn.functional.one_hot(torch.randint(0, 4, (8, 8)), 4).permute(2, 0, 1).float()
        >>> net(torch.rand(2, 1, 8, 8), w).shape
        torch.Size([2, 3, 8, 8])
    """

    def __init__(self, num_filters: int, width: int = 32, depth: int = 4, context_scale: int = 0) -> None:
        super().__init__()
        for label, v, lo in (("num_filters", num_filters, 1), ("width", width, 1), ("depth", depth, 1),
                             ("context_scale", context_scale, 0)):
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise ValueError(f"{label}: expected an integer >= {lo}, got {v!r}")
        self.num_filters, self.width, self.depth, self.context_scale = num_filters, width, depth, context_scale

        def conv(c_in, c_out):
            return [nn.Conv2d(c_in, c_out, 3, padding=1, padding_mode="reflect"), nn.ReLU(inplace=True)]

        layers: list[nn.Module] = []
        c = 2 * num_filters
        for _ in range(depth):
            layers += conv(c, width)
            c = width
        if context_scale:
            # the local path's features and the context's are merged by one more 3x3 convolution
            self.context = nn.Sequential(*conv(num_filters, width), *conv(width, width), *conv(width, width))
            self.merge = nn.Sequential(*conv(2 * width, width))
        layers.append(nn.Conv2d(c, 3, 1))
        self.body = nn.Sequential(*layers)

    @property
    def kwargs(self) -> dict:
        """The constructor's arguments (stored in a design file)."""
        out = {"num_filters": self.num_filters, "width": self.width, "depth": self.depth}
        return out | ({"context_scale": self.context_scale} if self.context_scale else {})

    def forward(self, raw: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        if raw.dim() != 4 or raw.shape[1] != 1:
            raise ValueError(f"raw: expected a (B, 1, H, W) mosaic, got {tuple(raw.shape)}")
        if weights.dim() == 3:
            weights = weights[None]
        if weights.dim() != 4 or weights.shape[1] != self.num_filters or weights.shape[-2:] != raw.shape[-2:]:
            raise ValueError(f"weights: expected ({self.num_filters}, H, W) or (B, {self.num_filters}, H, W) with "
                             f"H, W = {tuple(raw.shape[-2:])}, got {tuple(weights.shape)}")
        # named here (torch's own errors named no argument): the 3x3 reflect padding needs 2 samples a side, the
        # context path 2 blocks; the network's dtype; one weights map or one per item
        h, w_px = raw.shape[-2:]
        least = max(self.context_scale + 1, 2)
        if min(h, w_px) < least:
            why = f", the context path 2 blocks of {self.context_scale}" if self.context_scale else ""
            raise ValueError(f"raw: expected a mosaic of at least {least} x {least} pixels (the 3x3 convolutions need "
                             f"2 a side{why}), got {h} x {w_px}")
        dt = next(self.parameters()).dtype
        if raw.dtype != dt:
            raise ValueError(f"raw: expected the network's dtype {dt}, got {raw.dtype} (convert one to the other)")
        if weights.shape[0] not in (1, raw.shape[0]):
            raise ValueError(f"weights: expected 1 or {raw.shape[0]} maps (one per item), got {weights.shape[0]}")
        # (one NaN sample came out as 147 NaN outputs, and through the context path as the whole image)
        check_finite(raw, "raw")
        check_finite(weights, "weights")
        w = weights.to(raw.dtype).expand(raw.shape[0], -1, -1, -1)
        if (not self.context_scale and raw[0, 0].numel() > STRIP_PIXELS and h > 2 * STRIP_ROWS
                and not records_grad(raw, w, self)):
            # a large image in inference: strips of STRIP_ROWS rows, each with `depth` more on both sides (the
            # receptive field of the 3x3 convolutions; their reflect padding at a strip's cut reaches no further), so
            # the activations exist for one strip at a time; the image's own borders are the strips' borders
            halo, out = self.depth, []
            for r0 in range(0, h, STRIP_ROWS):
                r1 = min(h, r0 + STRIP_ROWS)
                a0, a1 = max(0, r0 - halo), min(h, r1 + halo)
                out.append(self._whole(raw[..., a0:a1, :], w[..., a0:a1, :])[..., r0 - a0:r1 - a0, :])
            return torch.cat(out, dim=-2)
        return self._whole(raw, w)

    def _whole(self, raw: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        sparse = raw * w
        x = torch.cat([sparse, w], dim=1)
        if x.device.type == "cpu":
            # oneDNN's CPU convolutions run faster on channels-last (NHWC) activations: a training step (forward and
            # backward, batch 16 of 64 x 64, width 32, depth 4, one thread) 137 -> 100 ms; the values are the same
            x = x.contiguous(memory_format=torch.channels_last)
        if not self.context_scale:
            return self.body(x).contiguous()
        feats = self.body[:-1](x)
        s = self.context_scale
        # each filter's block mean (0 where a block has none of its pixels)
        num = F.avg_pool2d(sparse, s, ceil_mode=True)
        den = F.avg_pool2d(w, s, ceil_mode=True)
        means = num / den.clamp_min(1e-6) * (den > 0)
        ctx = F.interpolate(self.context(means), size=raw.shape[-2:], mode="bilinear", align_corners=False)
        return self.body[-1](self.merge(torch.cat([feats, ctx], dim=1))).contiguous()
