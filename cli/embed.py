"""``spcodec embed``: an .spc wrapped, byte for byte, in a binary glTF."""

from __future__ import annotations

import argparse
from pathlib import Path

from spcodec.errors import UsageError

from .options import EXIT_OK

NAME = "embed"
HELP = ("wrap an .spc in a glTF (.glb): KHR_gaussian_splatting whose data is the .spc "
        "(SPCODEC_gaussian_splatting_compression_spc), upright in glTF's +Y")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file")
    p.add_argument("-o", "--output", required=True, help="the .glb to write")


def run(args: argparse.Namespace) -> int:
    from spcodec.fileio import atomic_write, check_writable, refuse_same_file
    from spcodec.gltf import compressed_glb_bytes

    if Path(args.output).suffix.lower() != ".glb":
        raise UsageError(f"cannot write {args.output}: embed writes a binary glTF, name it .glb")
    refuse_same_file(args.output, args.input)
    check_writable(args.output)
    data = Path(args.input).read_bytes()
    glb = compressed_glb_bytes(data)
    atomic_write(args.output, glb)
    print(f"{args.output}: {len(glb):,} bytes ({len(data):,} of them the .spc)")
    return EXIT_OK
