"""Shared fixtures: every core test that takes ``device`` / ``dtype`` runs on each available combination.

In the style of kornia's test base (``kornia/testing``): ``device`` is CPU, plus CUDA when a GPU is present
(the CUDA cases are skipped cleanly, with a reason, on machines without one); ``dtype`` is float32 and float64.
``tol(dtype)`` gives the comparison tolerances that fit each precision.
"""

from __future__ import annotations

import pytest
import torch

_DEVICES = ["cpu", "cuda"]
_DTYPES = {"float32": torch.float32, "float64": torch.float64}


@pytest.fixture(params=_DEVICES)
def device(request) -> torch.device:
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    return torch.device(request.param)


@pytest.fixture(params=list(_DTYPES), ids=list(_DTYPES))
def dtype(request) -> torch.dtype:
    return _DTYPES[request.param]


def tolerances(dtype: torch.dtype) -> dict:
    """``rtol`` / ``atol`` (relative to the data's scale) for results that differ only by float rounding."""
    return {"rtol": 1e-5, "atol": 1e-6} if dtype == torch.float32 else {"rtol": 1e-11, "atol": 1e-13}


@pytest.fixture
def tol():
    return tolerances
