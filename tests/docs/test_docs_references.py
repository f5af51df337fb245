"""Every isettorch name that the docs' ISETCam map and concept pages link to exists (the docs build itself,
with the gallery executed, runs in .ci/docs.sh)."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs"
ROLE = re.compile(r"\{(?:func|class|meth|mod)\}`~?(isettorch(?:\.\w+)+)`")


def _names() -> list[str]:
    names = set()
    for page in ("isetcam_map.md", "concepts.md", "viewer.md"):
        names.update(ROLE.findall((DOCS / page).read_text()))
    return sorted(names)


def _resolve(dotted: str):
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


def test_the_pages_link_to_names():
    assert len(_names()) > 40


@pytest.mark.parametrize("dotted", _names())
def test_linked_name_exists(dotted):
    assert _resolve(dotted) is not None
