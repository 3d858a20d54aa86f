"""`python -m garage_exp.exports DATASET [IMAGE] -o out.png` draws one exported frame: its COCO boxes (green,
visible part yellow) and its KITTI 3D boxes projected with the calib's P2 (red); given a job's `slots/` export
(bird's-eye views, garage_exp/slots/export.py), its slots read back from the COCO keypoints (red occupied, green
free) and marking points. Bad input: one line, exit 2."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from garage_exp.core import shell

COMMAND = shell.Command("garage_exp.exports")


def run(args: argparse.Namespace) -> int:
    from PIL import Image

    from garage_exp.exports import show
    from garage_exp.slots import export as slot_export

    slots = (args.dataset / "coco_keypoints.json").exists()
    rgb, name = (slot_export.draw if slots else show.draw)(args.dataset, args.image)
    out = args.output or Path(f"exports_{name}")
    Image.fromarray(rgb).save(out)
    print(out)
    return 0


def main(argv: list[str] | None = None) -> int:
    """The command in the one shell (garage_exp.core.shell): bad input one line and 2, Ctrl-C 130, SIGTERM 143."""
    ap = argparse.ArgumentParser(prog="python -m garage_exp.exports", description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, help="a job's dataset directory (dataset=true), or its slots/ directory")
    ap.add_argument("image", nargs="?", help="an image's file name in coco.json (default: the first)")
    ap.add_argument("-o", "--output", type=Path, help="PNG to write (default: exports_IMAGE here)")
    return COMMAND.run_args(ap, run, argv)


if __name__ == "__main__":
    sys.exit(main())
