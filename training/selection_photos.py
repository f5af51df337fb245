"""The selection photographs: public colour photographs, none from Kodak or McMaster, for selection decisions.

Kodak and McMaster are test sets only (``shared/data/README.md``), so a rule that selects a design, a checkpoint or a
setting needs other photographs. Until 2026-11-29 that was scikit-image's eight images (three of them a fundus
image, a telescope field and a microscope slide); their mean ranked pairs of designs no better than the seed spread
(``docs/training_log.md#codesign_context_seed_2026-11-28``). This script builds a larger set, chosen by what the
files are (natural photographs, no renders or illustrations), never by a score:

- scikit-image's wheel: ``astronaut``, ``chelsea``, ``coffee``, ``motorcycle_left``, ``rocket``;
- matplotlib's wheel: ``sample_data/grace_hopper.jpg``;
- scikit-learn 1.7.2's wheel: ``datasets/images/china.jpg`` and ``flower.jpg`` (the wheel file is passed in);
- Debian 12's ``mate-backgrounds`` 1.26.0-1 (its twelve ``nature`` photographs) and
  ``plasma-workspace-wallpapers`` 4:5.27.5-2 (its ten photographs; the other wallpapers are renders), the ``.deb``
  files passed in (``apt-get download mate-backgrounds plasma-workspace-wallpapers``).

Each photograph is reduced with Pillow's box filter (area averaging of the 8-bit sRGB values, in Pillow's fixed
point: within one level of the exact mean, half a level high on average) so that its long side is 768 pixels (Kodak's
size) unless it is already smaller, and written as 8-bit PNG. ``--check`` compares the written
files with the SHA-256 manifest ``selection_photos.json`` beside this script.

    apt-get download mate-backgrounds plasma-workspace-wallpapers
    pip download scikit-learn==1.7.2 --no-deps
    python training/selection_photos.py OUT_DIR --archives DIR_WITH_THOSE_FILES [--check]
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

MANIFEST = Path(__file__).with_suffix(".json")
LONG_SIDE_PX = 768

SKIMAGE = ("astronaut.png", "chelsea.png", "coffee.png", "motorcycle_left.png", "rocket.jpg")
SKLEARN_WHEEL = "scikit_learn-1.7.2-"
SKLEARN = ("sklearn/datasets/images/china.jpg", "sklearn/datasets/images/flower.jpg")
MATE_DEB = "mate-backgrounds_1.26.0-1_all.deb"
MATE = tuple(f"usr/share/backgrounds/mate/nature/{n}.jpg" for n in (
    "Aqua", "Blinds", "Dune", "FreshFlower", "Garden", "GreenMeadow", "LadyBird", "RainDrops", "Storm", "TwoWings",
    "Wood", "YellowFlower"))
PLASMA_DEB = "plasma-workspace-wallpapers_4%3a5.27.5-2_all.deb"
PLASMA = tuple(f"usr/share/wallpapers/{n}/contents/images/2560x1600.jpg" for n in (
    "BytheWater", "ColdRipple", "ColorfulCups", "DarkestHour", "EveningGlow", "FallenLeaf", "Grey", "OneStandsOut",
    "Path", "summer_1am"))


def _reduced_png(data: bytes) -> bytes:
    from PIL import Image

    im = Image.open(io.BytesIO(data)).convert("RGB")
    scale = LONG_SIDE_PX / max(im.size)
    if scale < 1:
        im = im.resize((round(im.width * scale), round(im.height * scale)), Image.Resampling.BOX)
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    return buf.getvalue()


def _archive(archives: Path, name: str) -> Path:
    hits = sorted(archives.glob(name + "*"))
    if not hits:
        raise FileNotFoundError(f"--archives: no file {name}* in {archives}")
    return hits[0]


def sources(archives: Path) -> list[tuple[str, bytes]]:
    """``[(output name, original file bytes)]`` for every selection photograph, in a fixed order."""
    import matplotlib
    import skimage

    out = [(Path(n).stem, (Path(skimage.__file__).parent / "data" / n).read_bytes()) for n in SKIMAGE]
    out.append(("grace_hopper", (Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg").read_bytes()))
    with zipfile.ZipFile(_archive(archives, SKLEARN_WHEEL)) as z:
        out += [(Path(m).stem, z.read(m)) for m in SKLEARN]
    for deb, members, prefix in ((MATE_DEB, MATE, "mate_"), (PLASMA_DEB, PLASMA, "plasma_")):
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run(["dpkg-deb", "-x", str(_archive(archives, deb)), tmp], check=True)
            for m in members:
                name = Path(m).stem if prefix == "mate_" else Path(m).parts[3]
                out.append((prefix + name, (Path(tmp) / m).read_bytes()))
    return out


def build(out_dir: Path, archives: Path) -> dict[str, str]:
    """Write the selection photographs to ``out_dir``; ``{file name: sha256}``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    digests = {}
    for name, data in sources(archives):
        png = _reduced_png(data)
        (out_dir / f"{name}.png").write_bytes(png)
        digests[f"{name}.png"] = hashlib.sha256(png).hexdigest()
    return digests


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--archives", type=Path, required=True, help="folder with the two .deb files and the wheel")
    ap.add_argument("--check", action="store_true", help="compare with selection_photos.json")
    ap.add_argument("--write-manifest", action="store_true")
    args = ap.parse_args(argv)
    digests = build(args.out, args.archives)
    print(f"{len(digests)} photographs in {args.out}")
    if args.write_manifest:
        MANIFEST.write_text(json.dumps(digests, indent=1) + "\n")
    if args.check:
        want = json.loads(MANIFEST.read_text())
        bad = sorted(k for k in set(want) | set(digests) if want.get(k) != digests.get(k))
        if bad:
            print(f"differ from {MANIFEST.name}: {bad}")
            return 1
        print(f"all {len(want)} match {MANIFEST.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
