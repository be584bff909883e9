"""``spcodec attach-preview``: a small .spc embedded in another as its preview (spec 7.4)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .options import EXIT_OK, MAX_LAYER

NAME = "attach-preview"
HELP = ("embed a small .spc in another as its preview (spec 7.4), which streaming viewers show "
        "first")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="the .spc file to add the preview to")
    p.add_argument("preview", help="a small whole .spc file of the same scene (encode it with "
                   "--target-size for a tenth of the bytes, say)")
    p.add_argument("-o", "--output", required=True, help="the .spc file to write")
    p.add_argument("--takeover", type=MAX_LAYER, default=None, metavar="K",
                   help="show the preview until layers 0..K have arrived: %(type)s (default: the "
                   "first layer whose prefix scores at least the preview on the encoder's "
                   "training views, as both files' metadata record them; else the last layer)")


def run(args: argparse.Namespace) -> int:
    from spcodec.decoder import inspect
    from spcodec.fileio import atomic_write, check_writable, refuse_same_file
    from spcodec.preview import attach_preview, choose_takeover, recorded_prefix_psnr

    refuse_same_file(args.output, args.scene, args.preview)
    check_writable(args.output)
    scene, preview = Path(args.scene).read_bytes(), Path(args.preview).read_bytes()
    takeover = args.takeover
    if takeover is None:
        scores = recorded_prefix_psnr(inspect(preview).metadata)
        info = inspect(scene)
        takeover = choose_takeover(recorded_prefix_psnr(info.metadata), len(info.header.layers),
                                   scores[-1]["psnr"] if scores else None)
    data = attach_preview(scene, preview, takeover)
    atomic_write(args.output, data)
    print(f"{args.output}: {len(data):,} bytes, the preview ({len(preview):,} bytes) shown "
          f"until layer {takeover} arrives")
    return EXIT_OK
