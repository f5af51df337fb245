"""Where the tests find the project's shared data (imported as ``shared_paths``: pytest puts ``tests/`` on the
path for its conftest)."""

import os
from pathlib import Path

# The project's shared folder (ISETCam parity cases, the Kodak and McMaster test images) beside the checkout, as the
# developers' brief places it (``../shared``), or wherever ``ISETTORCH_SHARED`` points; the benchmark images where
# ``ISETTORCH_DATA`` points (as isettorch.paths), else in the shared folder's data/. Tests that need them skip
# with a reason naming the path when they are absent.
SHARED = Path(os.environ.get("ISETTORCH_SHARED") or Path(__file__).resolve().parents[1].parent / "shared")
DATA = Path(os.environ.get("ISETTORCH_DATA") or SHARED / "data")
PARITY_DIR = SHARED / "isetcam-parity"
PARITY_CASE = PARITY_DIR / "macbeth_d65_default.npz"
