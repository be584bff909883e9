"""``spcodec decode``: an .spc (or the one a .glb carries) to a PLY, a .glb or an SPZ."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from spcodec.errors import UsageError

from .options import EXIT_OK, MAX_LAYER, report_stream
from .scenes import spc_source

NAME = "decode"
HELP = "decode an .spc file into a 3DGS PLY or a glTF (.glb)"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file (gzip-wrapped or not), or a prefix of one, or a "
                   ".glb that 'spcodec embed' wrote")
    p.add_argument("-o", "--output", required=True,
                   help="the file to write: a 3DGS PLY (INRIA layout; a .ply name, a device or "
                   "- for standard output), with a .glb name a binary glTF with "
                   "KHR_gaussian_splatting, or with a .spz name a Niantic SPZ (v3)")
    p.add_argument("--max-layer", type=MAX_LAYER, default=None, metavar="K",
                   help="decode layers 0..K only (0 = the sketch layer alone); %(type)s "
                   "(default: every layer)")
    p.add_argument("--preview", action="store_true",
                   help="decode the file's preview (spec 7.4), the small scene a viewer shows "
                   "first, instead of the scene (default: off)")


def run(args: argparse.Namespace) -> int:
    from spcodec.decoder import decode_layers, inspect
    from spcodec.fileio import check_writable, is_stdout, refuse_same_file
    from spcodec.gltf import write_glb
    from spcodec.ply import write_ply

    suffix = "" if is_stdout(args.output) else Path(args.output).suffix.lower()
    if suffix == ".gltf":
        raise UsageError(f"cannot write {args.output}: name it .glb (binary glTF); text .gltf with "
                         "a separate buffer is not supported")
    if suffix not in ("", ".ply", ".glb", ".spz"):
        raise UsageError(f"cannot write {args.output}: decode writes a 3DGS PLY (.ply, or - for "
                         f"standard output), a binary glTF (.glb) or an SPZ (.spz), not {suffix}")
    refuse_same_file(args.output, args.input)
    check_writable(args.output)
    if args.preview and args.max_layer is not None:
        raise UsageError("--max-layer chooses layers of the scene, --preview decodes the "
                         "preview instead: give one of them")
    source = spc_source(args.input)
    start = time.perf_counter()
    if args.preview:
        cloud, counts = _decode_preview(source, args.input)
    else:
        result = decode_layers(source, max_layer=args.max_layer)
        cloud = result.cloud
        counts = ", ".join(f"L{layer.index} {len(layer.cloud)}" for layer in result.layers)
    elapsed = time.perf_counter() - start
    if suffix == ".glb":  # upright in glTF's +Y, from the up axis the file stores
        write_glb(args.output, cloud, up=(inspect(source).metadata or {}).get("up"))
    elif suffix == ".spz":  # Niantic SPZ v3 (gzip), which every SPZ reader opens
        from spcodec.formats import write_scene
        write_scene(args.output, cloud, "spz")
    else:
        write_ply(args.output, cloud)
    print(f"decoded {len(cloud)} Gaussians ({counts}) in {elapsed * 1000:.0f} ms -> "
          f"{'standard output' if is_stdout(args.output) else args.output}",
          file=report_stream(args.output))
    return EXIT_OK


def _decode_preview(source, path: str):
    """The preview's Gaussians and a note for the report line; a file without one is the
    user's mistake (a one-line error), not an empty output."""
    from spcodec.decoder import decode_preview

    preview = decode_preview(source)
    if preview is None:
        raise UsageError(f"{path} has no preview (spec 7.4); decode it without --preview")
    return preview.cloud, f"the preview, shown until layer {preview.takeover_layer} arrives"
