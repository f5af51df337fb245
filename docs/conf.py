"""Sphinx configuration of the isettorch docs (``.ci/docs.sh`` builds them with warnings as errors).

Sphinx + sphinx-gallery rather than mkdocs: the gallery runs every example at build time and fails the build
on an exception (sphinx-gallery is what NumPy-world libraries such as scikit-image and matplotlib use), autodoc
reads the docstrings (Google style via napoleon) with cross-references checked under ``-W``, and MyST lets the
benchmark tables in ``benchmarks/*.md`` be included as they are.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("OMP_NUM_THREADS", "1")  # tiny gallery tensors: a second thread only waits (.ci/docs.sh)

import isettorch  # noqa: E402

project = "isettorch"
author = "isettorch contributors"
copyright = "2026, isettorch contributors"
release = version = isettorch.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "examples/README.rst", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.json", "auto_examples/*.md5"]
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3

autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # signatures show the defaults; the docstrings say the types and units
autodoc_mock_imports: list[str] = []
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False

sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("matplotlib",),
    "matplotlib_animations": False,
    "show_memory": False,
}

html_theme = "furo"
html_title = f"isettorch {release}"
html_static_path: list[str] = []
nitpicky = False
