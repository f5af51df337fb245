"""Matplotlib helpers shared by the plotting methods. Every function returns the Figure, which can be
saved with ``fig.savefig("x.png")``. The Agg backend is used when no display is available."""

from __future__ import annotations

import matplotlib

if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg") and not __import__("os").environ.get("DISPLAY"):
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402


def _fig_ax(ax):
    if ax is None:
        fig, ax = plt.subplots(figsize=(5, 4))
    else:
        fig = ax.figure
    return fig, ax


def show_image(img: torch.Tensor, title: str = "", ax=None):
    """Show a [3, H, W] or [H, W] image in [0, 1]."""
    fig, ax = _fig_ax(ax)
    a = img.detach().float().cpu()
    if a.dim() == 3:
        a = a.permute(1, 2, 0)
        ax.imshow(a.clamp(0, 1).numpy())
    else:
        ax.imshow(a.numpy(), cmap="gray")
    ax.set_title(title)
    ax.axis("off")
    return fig


def plot_spectrum(wavelengths_nm: torch.Tensor, values: torch.Tensor, ylabel: str = "", title: str = "", ax=None):
    fig, ax = _fig_ax(ax)
    ax.plot(wavelengths_nm.detach().cpu().numpy(), values.detach().cpu().numpy(), "-o", ms=3)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    return fig


def plot_curves(x, ys: dict, xlabel: str = "", ylabel: str = "", title: str = "", ax=None, logy: bool = False):
    """Several curves against one x axis; ``ys`` maps label -> values."""
    fig, ax = _fig_ax(ax)
    for label, y in ys.items():
        xx = x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else x
        yy = y.detach().cpu().numpy() if isinstance(y, torch.Tensor) else y
        ax.plot(xx, yy, label=str(label))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if logy:
        ax.set_yscale("log")
    if len(ys) > 1:
        ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    return fig
