"""Whether autograd records an operation now: the one test behind every fast path that writes in place, reuses a
cached buffer or leaves torch (NumPy, SciPy) when no gradient is wanted; and caches of tensors that autograd may
use later."""

from __future__ import annotations

import contextlib
import functools

import torch


def records_grad(*values) -> bool:
    """True when grad mode is on and one of ``values`` is a tensor that requires grad or a module with a parameter
    that does; other values (``None``, numbers, arrays) are ignored.

    Example:
        >>> records_grad(torch.ones(2, requires_grad=True), None)
        True
        >>> with torch.no_grad():
        ...     records_grad(torch.ones(2, requires_grad=True))
        False
    """
    if not torch.is_grad_enabled():
        return False
    for v in values:
        if isinstance(v, torch.Tensor):
            if v.requires_grad:
                return True
        elif isinstance(v, torch.nn.Module) and any(p.requires_grad for p in v.parameters()):
            return True
    return False


def safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """sqrt with a finite gradient (0) at x <= 0: no sqrt(0) trap (zero light, an OTF's DC, a zero noise level)."""
    pos = x > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x))


def tensor_cache(maxsize: int):
    """``functools.lru_cache(maxsize)`` whose misses are computed outside ``torch.inference_mode``: a tensor first
    cached under inference mode is an inference tensor, which autograd refuses to save for backward in every later
    call (a learned demosaic run once in an ``inference_mode`` validation stopped the training step after it)."""
    def decorate(fn):
        @functools.wraps(fn)
        def fill(*args, **kwargs):
            with torch.inference_mode(False):
                return fn(*args, **kwargs)
        return functools.lru_cache(maxsize=maxsize)(fill)
    return decorate


_AUTOCAST_DEVICES = ("cpu", "cuda")


def full_precision(fn):
    """Run ``fn`` (a stage of the physics: optics, sensor, camera, ISP, a training-pair batch) with a caller's
    ``torch.autocast`` turned off, so it computes in its inputs' float32 / float64 as documented (under CPU bfloat16
    autocast the sensor's sampling product came back bfloat16 and was refused as 'electron_rate', and a stream's OTF
    product moved its float32 batch by 3.5e-4 unsaid). A network that runs after it still autocasts."""
    @functools.wraps(fn)
    def run(*args, **kwargs):
        on = [d for d in _AUTOCAST_DEVICES if torch.is_autocast_enabled(d)]
        if not on:
            return fn(*args, **kwargs)
        with contextlib.ExitStack() as stack:
            for d in on:
                stack.enter_context(torch.autocast(d, enabled=False))
            return fn(*args, **kwargs)
    return run
