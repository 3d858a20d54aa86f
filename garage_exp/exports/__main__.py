"""`python -m garage_exp.exports DATASET [IMAGE] -o out.png` draws one exported frame: its COCO boxes (green,
visible part yellow) and its KITTI 3D boxes projected with the calib's P2 (red). Bad input: one line, exit 2."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from garage_exp.core.errors import GarageError


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m garage_exp.exports", description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, help="a job's dataset directory (dataset=true)")
    ap.add_argument("image", nargs="?", help="an image's file name in coco.json (default: the first)")
    ap.add_argument("-o", "--output", type=Path, help="PNG to write (default: exports_IMAGE here)")
    args = ap.parse_args(argv)
    try:
        from PIL import Image

        from garage_exp.exports.show import draw

        rgb, name = draw(args.dataset, args.image)
    except GarageError as exc:
        print(f"garage_exp.exports: {exc}", file=sys.stderr)
        return 2
    out = args.output or Path(f"exports_{name}")
    Image.fromarray(rgb).save(out)
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
