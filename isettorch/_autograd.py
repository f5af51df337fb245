"""Whether autograd records an operation now: the one test behind every fast path that writes in place, reuses a
cached buffer or leaves torch (NumPy, SciPy) when no gradient is wanted."""

from __future__ import annotations

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
