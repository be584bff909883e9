"""The ``spcodec`` command line.

Every failure ends with one line on stderr (``spcodec: error: ...``) and a non-zero exit code; no
traceback for a bad file or a bad argument (``--debug`` shows one), and no partial output file.
Commands that need the encoder's heavy dependencies import them only when they run, and say which
extra to install when they are missing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Callable, NoReturn, Sequence

from .errors import FormatError, Interrupted, SpcodecError, TruncatedError, UsageError
from .limits import DEFAULT_LIMITS

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2
EXIT_BROKEN_PIPE = 141
"""What a shell reports for a program ended by SIGPIPE (128 + 13), as `cat big | head` does."""

Handler = Callable[[argparse.Namespace], int]
Configure = Callable[[argparse.ArgumentParser], None]
COMMANDS: dict[str, tuple[str, Configure, Handler]] = {}


class Bounded:
    """An argparse ``type``: a number within a range, checked while the command line is parsed
    (before any work starts) and shown by ``--help`` through ``%(type)s``."""

    def __init__(self, kind: type = int, low: float = 1, high: float | None = None,
                 exclusive: bool = False) -> None:
        self.kind, self.low, self.high, self.exclusive = kind, low, high, exclusive

    def __call__(self, text: str) -> int | float:
        try:
            value = self.kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {self}, got {text!r}") from None
        above = value > self.low if self.exclusive else value >= self.low
        if not (math.isfinite(value) and above and (self.high is None or value <= self.high)):
            raise argparse.ArgumentTypeError(f"must be {self}, got {text}")
        return value

    def __str__(self) -> str:
        noun = "an integer" if self.kind is int else "a number"
        if self.high is not None:
            return f"{noun} in {self.low}..{self.high}"
        return f"{noun} {'>' if self.exclusive else '>='} {self.low}"


def closeup_list(text: str) -> tuple[float, ...]:
    """An argparse ``type``: comma-separated distance factors in (0, 1), or ``none``."""
    if text.strip().lower() == "none":
        return ()
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected factors such as 0.5,0.25 or none, got "
                                         f"{text!r}") from None
    if not all(0 < v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"each factor must lie strictly between 0 and 1, got "
                                         f"{text}")
    return values


SEED = Bounded(int, 0, 2**32 - 1)
"""Seeds of numpy and scikit-learn: non-negative and below 2**32."""
MAX_LAYER = Bounded(int, 0)
PORT = Bounded(int, 0, 65535)
THROTTLE = Bounded(float, 0, exclusive=True)
"""``serve --throttle`` in kbit/s: any positive speed."""
PATCH_LAYERS_DEFAULT, RETRAINED_PATCH_LAYERS = 3, 6
"""``PatchConfig.layers`` and ``encoder.config.RETRAINED_PATCH_LAYERS``, for --help without importing
the encoder; a test keeps them equal."""
RETRAIN_DEFAULTS = {"iterations": 3000, "finish_iterations": 600, "views": 96, "resolution": 400,
                    "close_views": 96, "nested_full_share": 0.75}
"""``RetrainConfig`` defaults shown by --help (the same test keeps them equal)."""
VIEWER_BLUR_VARIANCE, DATASET_BLUR_VARIANCE = 0.075, 0.3
"""``encoder.config.VIEWER_BLUR_VARIANCE`` and ``DATASET_BLUR_VARIANCE``, the defaults of encode's
--blur-variance without and with --dataset; the second is also eval's (the same test)."""
DEVICE_HELP = ("auto: CUDA when torch sees a GPU (rendered by gsplat when installed, else by the "
               "torch renderer), else the CPU (default: %(default)s)")
"""--device of encode and of the commands that render: one device rule (resolve_device)."""
CHECKPOINT_EVERY = 500
"""``RunControl.checkpoint_every``, for --help (a test keeps them equal)."""
DEFAULT_THREADS = 1
"""Torch threads for encodes that render or train when --threads is not given: the CPU renderer
runs many small tensor operations that more threads barely speed up, while two threads on this
project's busy 2-core machine ran retraining 4-8x slower than one (docs/RESULTS.md, section 13)."""
MAX_TURNTABLE = 64
"""Views in a turntable contact sheet (64 views of 400 pixels make a 3,200-pixel square)."""
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
"""The values of --up, and the ones an .spc's metadata may store."""


def command(name: str, help_text: str, configure: Configure):
    """Register ``fn(args) -> exit code`` as sub-command ``name``; ``configure`` adds its options."""
    def wrap(fn: Handler) -> Handler:
        COMMANDS[name] = (help_text, configure, fn)
        return fn
    return wrap


# --------------------------------------------------------------------------------- decode
def _add_decode(p: argparse.ArgumentParser) -> None:
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


@command("decode", "decode an .spc file into a 3DGS PLY or a glTF (.glb)", _add_decode)
def cmd_decode(args: argparse.Namespace) -> int:
    from .decoder import decode_layers, inspect
    from .fileio import check_writable, is_stdout, refuse_same_file
    from .gltf import write_glb
    from .ply import write_ply

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
        from .formats import write_scene
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
    from .decoder import decode_preview

    preview = decode_preview(source)
    if preview is None:
        raise UsageError(f"{path} has no preview (spec 7.4); decode it without --preview")
    return preview.cloud, f"the preview, shown until layer {preview.takeover_layer} arrives"


# ---------------------------------------------------------------------------------- embed
def _add_embed(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file")
    p.add_argument("-o", "--output", required=True, help="the .glb to write")


@command("embed", "wrap an .spc in a glTF (.glb): KHR_gaussian_splatting whose data is the .spc "
         "(SPCODEC_gaussian_splatting_compression_spc), upright in glTF's +Y", _add_embed)
def cmd_embed(args: argparse.Namespace) -> int:
    from .fileio import atomic_write, check_writable, refuse_same_file
    from .gltf import compressed_glb_bytes

    if Path(args.output).suffix.lower() != ".glb":
        raise UsageError(f"cannot write {args.output}: embed writes a binary glTF, name it .glb")
    refuse_same_file(args.output, args.input)
    check_writable(args.output)
    data = Path(args.input).read_bytes()
    glb = compressed_glb_bytes(data)
    atomic_write(args.output, glb)
    print(f"{args.output}: {len(glb):,} bytes ({len(data):,} of them the .spc)")
    return EXIT_OK


# ----------------------------------------------------------------------------------- info
def _add_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file, or a .glb that 'spcodec embed' wrote")
    p.add_argument("--json", action="store_true", help="print a JSON document (default: text)")
    p.add_argument("--verify", action="store_true",
                   help="also check the CRC-32 of every section, reading the whole file; a "
                   "damaged one fails the command, named by layer and section (default: off, "
                   "only the header is read)")


@command("info", "describe an .spc file: version, layers, sections and their byte ranges",
         _add_info)
def cmd_info(args: argparse.Namespace) -> int:
    from .decoder import inspect
    from .decoder.api import verify_sections

    other = _other_scene_file(args.input)
    if other is not None:  # an SPZ, .splat, SOG... : one line on it instead of "bad magic"
        print(json.dumps(other) if args.json else f"{args.input}: {other['description']}")
        return EXIT_OK
    source = spc_source(args.input)
    doc = inspect(source).to_json()
    if args.verify:  # before any output: a damaged file gets the error line alone
        doc["verified_sections"] = verify_sections(source)
    if not isinstance(source, str):
        doc["embedded_in"] = "glb"
    if args.json:
        print(json.dumps(doc, indent=2))
        return EXIT_OK
    print(f"{args.input}: spcodec bitstream v{doc['version']}, {doc['gaussians']} Gaussians, "
          f"SH degree {doc['sh_degree']}, {doc['stored_size']} bytes"
          f"{' (gzip-wrapped)' if doc['gzip'] else ''}"
          f"{' embedded in a glTF' if 'embedded_in' in doc else ''}")
    if doc["complete_layers"] < len(doc["layers"]):
        print(_partial_file_note(doc))
    print("layers:")
    scores = _prefix_scores(doc["metadata"])
    for layer in doc["layers"]:
        end = layer["end_offset"] if layer["end_offset"] is not None else \
            f"{layer['inner_end_offset']} of the inflated file"
        state = f"complete at byte {end}" if layer["complete"] else \
            f"INCOMPLETE (needs the bytes up to {end})"
        score = f"; layers 0..{layer['index']}: {scores[layer['index']]:.2f} dB on the " \
            "encoder's training views" if layer["index"] in scores else ""
        print(f"  L{layer['index']:<3} {layer['kind']:<7} {layer['gaussians']:>10} Gaussians, "
              f"{state}{score}")
    print("sections:")
    for s in doc["sections"]:
        print(f"  #{s['index']:<3} L{s['layer']:<3} {s['type']:<20} {s['codec']:<5} "
              f"offset {s['offset']:>10}  {s['length']:>10} bytes  (raw {s['raw_length']})")
    if "preview" in doc:
        print(_preview_line(doc["preview"]))
    if doc["metadata"]:
        print("metadata: " + json.dumps(doc["metadata"], sort_keys=True)[:200])
    if args.verify:
        print(f"all {doc['verified_sections']} sections verified (CRC-32)")
    return EXIT_OK


def _other_scene_file(path: str) -> dict | None:
    """For ``info``: a scene file of another tool (SPZ, .splat, SOG, .ksplat, PLY) described in
    one line, or None for an .spc, a .glb or anything unrecognized (which ``inspect`` judges)."""
    from . import formats

    if not (os.path.isfile(path) or os.path.isdir(path)):
        return None
    fmt = formats.detect(path)
    if fmt is None or fmt.key == "spc":
        return None
    text = formats.describe(path) if fmt.describe else None
    if text is None:
        cloud = formats.read_scene(path)
        text = f"{fmt.name}, {len(cloud):,} Gaussians, SH degree {cloud.sh_degree}"
    return {"format": fmt.key, "description": f"{text} (not an .spc; 'spcodec encode' reads it)"}


def _preview_line(preview: dict) -> str:
    """``info``'s line on the preview (spec 7.4)."""
    if "error" in preview:
        return f"preview: does not decode ({preview['error']}); viewers show the layers alone"
    if not preview.get("complete", True):
        return f"preview: INCOMPLETE (needs the bytes up to {preview['end_offset']})"
    return (f"preview: {preview['gaussians']} Gaussians in {preview['bytes']} bytes, complete at "
            f"byte {preview['end_offset']}; shown until layer {preview['takeover_layer']} arrives")


def _prefix_scores(metadata) -> dict[int, float]:
    """Layer -> the PSNR the encoder measured for the prefix ending there (metadata
    ``stats.prefix_psnr``)."""
    from .preview import recorded_prefix_psnr

    return {entry["layer"]: entry["psnr"] for entry in recorded_prefix_psnr(metadata)}


def _partial_file_note(doc: dict) -> str:
    """What ``info`` says of a file that holds only some of its layers."""
    k, have, size = doc["complete_layers"], doc["available_bytes"], doc["file_size"]
    where = f"after {have} of its {size} bytes{' (inflated)' if doc['gzip'] else ''}"
    whole = f"layers 0..{k - 1} are complete" if k else "no layer is complete"
    if not doc["truncated"]:
        return f"PREFIX: the data ends at a layer boundary, {where}; {whole} and decode"
    hint = f" (decode them with --max-layer {k - 1})" if k else ""
    return f"TRUNCATED: the data ends inside layer {k}, {where}; {whole}{hint}"


def spc_source(path: str) -> str | bytes:
    """What to decode for ``path``: the path itself, or for a binary glTF the .spc that
    ``spcodec embed`` put inside it (a glTF without one is named as such, not "bad magic")."""
    from .gltf import GLB_MAGIC, embedded_spc

    if not os.path.isfile(path):  # a pipe or device is read once, by the decoder alone
        return path
    with open(path, "rb") as fh:
        if fh.read(len(GLB_MAGIC)) != GLB_MAGIC:
            return path
    DEFAULT_LIMITS.check("input file size", os.path.getsize(path), DEFAULT_LIMITS.max_file_bytes)
    return embedded_spc(Path(path).read_bytes(), path)


# ------------------------------------------------------------------------- attach-preview
def _add_attach_preview(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="the .spc file to add the preview to")
    p.add_argument("preview", help="a small whole .spc file of the same scene (encode it with "
                   "--target-size for a tenth of the bytes, say)")
    p.add_argument("-o", "--output", required=True, help="the .spc file to write")
    p.add_argument("--takeover", type=MAX_LAYER, default=None, metavar="K",
                   help="show the preview until layers 0..K have arrived: %(type)s (default: the "
                   "first layer whose prefix scores at least the preview on the encoder's "
                   "training views, as both files' metadata record them; else the last layer)")


@command("attach-preview", "embed a small .spc in another as its preview (spec 7.4), which "
         "streaming viewers show first", _add_attach_preview)
def cmd_attach_preview(args: argparse.Namespace) -> int:
    from .decoder import inspect
    from .fileio import atomic_write, check_writable, refuse_same_file
    from .preview import attach_preview, choose_takeover, recorded_prefix_psnr

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


# ---------------------------------------------------------------------------------- serve
def _add_serve(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="the scene to show at /: an .spc (streamed layer by layer), or a "
                   ".ply or .glb (loaded whole, for comparison)")
    p.add_argument("--port", type=PORT, default=8000,
                   help="TCP port: %(type)s (default: %(default)s; 0 = any free port)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--throttle", type=THROTTLE, metavar="KBPS", default=None,
                   help="send the scene at this many kilobits per second, %(type)s (e.g. 20000 "
                   "for 20 Mbit/s), to watch layers arrive as on a slow connection (default: "
                   "no limit)")
    p.add_argument("--log", action="store_true",
                   help="log every request on stderr (default: quiet)")
    p.add_argument("--up", choices=["+x", "-x", "+y", "-y", "+z", "-z"], default=None,
                   metavar="AXIS", help="the scene's up axis where the file does not store one (a "
                   ".ply; an .spc says which way is up): one of +x -x +y -y +z -z, written as "
                   "--up=+z (default: what the file says, else -y)")


@command("serve", "serve the streaming web viewer and an .spc (with HTTP range requests)",
         _add_serve)
def cmd_serve(args: argparse.Namespace) -> int:
    from .serve import make_server, viewer_missing

    server = make_server([args.input], host=args.host, port=args.port,
                         throttle_kbps=args.throttle, log=args.log, up=args.up)
    host, port = server.server_address[:2]
    shown = f"[{host}]" if ":" in host else host
    problem = viewer_missing()
    if problem:
        print(f"spcodec: warning: {problem}; serving the file alone", file=sys.stderr)
    if host not in ("127.0.0.1", "::1", "localhost"):
        print(f"spcodec: warning: listening on {host}: other machines can fetch the scene and the "
              "viewer", file=sys.stderr)
    speed = f", throttled to {args.throttle:g} kbit/s" if args.throttle else ""
    print(f"serving {args.input}{speed}: open http://{shown}:{port}/  (Ctrl-C stops)", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopped")
    finally:
        server.server_close()
    return EXIT_OK


# ----------------------------------------------------------------------------------- demo
def _add_demo(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output-dir", default="spcodec-demo",
                   help="folder for demo.spc and demo.ply, created if missing (default: "
                   "%(default)s)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="seed of the built-in scene: %(type)s (default: %(default)s)")


@command("demo", "run the pipeline on a built-in synthetic scene and write demo.spc/demo.ply",
         _add_demo)
def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    return run_demo(Path(args.output_dir), seed=args.seed)


# ----------------------------------------------------------------------------- conformance
def _add_conformance(p: argparse.ArgumentParser) -> None:
    p.add_argument("--decoder", metavar="'CMD {input} {output}'",
                   help="judge this command line instead of the in-process decoder: it must write "
                        "an INRIA PLY to {output} and exit 0, or exit non-zero, write nothing and "
                        "print [error-code] on stderr (conformance/README.md) (default: the "
                        "in-process decoder)")
    p.add_argument("--max-layer-arg", metavar="'--max-layer {k}'",
                   help="what to append to --decoder for a decode of layers 0..k (without it, "
                        "those decodes are not run) (default: none)")
    p.add_argument("--json", action="store_true", help="print the results as one JSON document (default: "
                   "a table)")
    p.add_argument("--only", nargs="+", metavar="PATTERN",
                   help="run only the vectors whose id matches a shell-style pattern (default: "
                   "every vector)")
    p.add_argument("--without-zstd", action="store_true",
                   help="the decoder has no zstd support: decodes that need it expect "
                        "codec-unavailable (default: off)")
    p.add_argument("--timeout", type=Bounded(float, 0, exclusive=True), default=None, metavar="S",
                   help="seconds an external decode may take: %(type)s (default: 60)")
    p.add_argument("--suite", metavar="DIR", help="the suite to run (default: the one installed "
                   "with spcodec)")
    p.add_argument("--generate", metavar="DIR",
                   help="instead of running, regenerate every vector and the manifest into DIR "
                        "(e.g. conformance/ in the repository) (default: off)")


@command("conformance", "check a decoder against the conformance vectors (or regenerate them)",
         _add_conformance)
def cmd_conformance(args: argparse.Namespace) -> int:
    from .conformance.command import run

    return run(args)


# ---------------------------------------------------------------------------------- encode
def _add_encode(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="a trained 3DGS scene: a PLY (INRIA layout or compressed.ply), "
                   "SPZ, antimatter15 .splat, PlayCanvas SOG (.sog or its folder) or .ksplat, "
                   "recognized by content")
    p.add_argument("-o", "--output", required=True, help="the .spc file to write")
    p.add_argument("--preset", choices=["lowrate", "balanced", "highrate", "transparent"],
                   default="balanced",
                   help="rate/quality operating point: codebooks, sketch threshold and patch "
                   "downsample; transparent keeps every Gaussian, never retrains, and aims to "
                   "look like the input in a viewer (default: %(default)s)")
    p.add_argument("--codec", choices=["zlib", "zstd"], default="zlib",
                   help="section codec; zlib: every decoder reads it and the Python one "
                   "fastest, zstd: optional, each frame checked against spec 1.1.1's rules "
                   "(default: %(default)s)")
    p.add_argument("--gzip", action="store_true", help="wrap the file in gzip (default: off)")
    p.add_argument("--no-sketch", action="store_true",
                   help="encode every Gaussian as patch (default: off)")
    p.add_argument("--patch-layers", type=Bounded(int, 1, DEFAULT_LIMITS.max_layers - 1),
                   default=None, metavar="N",
                   help="number of patch layers: %(type)s; each holds 1.5 times the Gaussians of "
                   f"the one before, except that {PATCH_LAYERS_DEFAULT} hold 7, 16.5 and 76.5 %% "
                   f"of the patch (default: {RETRAINED_PATCH_LAYERS} when retraining, "
                   f"{PATCH_LAYERS_DEFAULT} with --no-retrain)")
    p.add_argument("--position-bits", type=Bounded(int, 8, 30), default=None, metavar="B",
                   help="bits of precision of the patch positions over each layer's box: "
                   "%(type)s (default: 12 of the scene's extent when retraining, 16 without, "
                   "14 for --preset transparent)")
    p.add_argument("--tau-max", type=Bounded(float, 0, exclusive=True), default=None,
                   metavar="TAU", help="polynomial-model error threshold of sketch clusters "
                   "(unitless): %(type)s (default: set by --preset)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="seed of every random choice: %(type)s (default: %(default)s)")
    p.add_argument("--jobs", type=Bounded(int, 1), default=None, metavar="N",
                   help="worker processes: %(type)s (default: all cores)")
    p.add_argument("--stats", metavar="FILE",
                   help="also write the encode statistics as JSON (default: none)")
    p.add_argument("--quiet", action="store_true", help="no progress display (default: off)")

    size = p.add_argument_group("size")
    size.add_argument("--target-size", metavar="SIZE",
                      help="a file of at most SIZE bytes: 150k, 2MB, 300000 (k, M "
                      "decimal; KiB, MiB binary); sets how many patch Gaussians survive pruning "
                      "and, below 8,192 of them, shrinks the codebooks to match; with "
                      "--no-retrain, wherever some precision fits every Gaussian, keeps them all "
                      "and chooses each attribute's codebook by rate and predicted distortion "
                      "instead (default: none, the preset's downsample)")
    size.add_argument("--target-psnr", type=Bounded(float, 10, 100), metavar="DB",
                      help="the smallest file whose close-up (eval's views at half the distance, "
                      "800x800) reaches DB against the input: %(type)s; sets how many patch "
                      "Gaussians survive (default: none)")
    size.add_argument("--preview-size", metavar="SIZE",
                      help="embed a preview of at most SIZE bytes (spec 7.4): the scene encoded "
                      "a second time for that size, which viewers show until the file's own "
                      "layers beat it; with --target-size the whole file stays within the "
                      "target. Pays on scenes whose quality falls slowly with size "
                      "(docs/RESULTS.md 15.8); doubles the encode time (default: none)")
    size.add_argument("--patch-downsample", type=Bounded(float, 1), metavar="N",
                      help="keep 1/N of the patch Gaussians: %(type)s (default: set by --preset: "
                      "lowrate 8, balanced 4, highrate 2)")
    size.add_argument("--prune", choices=["importance", "sampled", "uniform"], default=None,
                      help="which patch Gaussians survive: the largest blend weight over the "
                      "training views, a random sample in proportion to it, or uniformly at "
                      "random as in the paper (default: importance)")

    train = p.add_argument_group("retraining")
    train.add_argument("--no-retrain", action="store_true",
                       help="skip retraining: code the patch as it is; seconds instead of "
                       "minutes, larger files (default: off)")
    train.add_argument("--dataset", metavar="DIR", help="retrain against this dataset's training "
                       "images (COLMAP, transforms.json or LLFF; its test split is held out) "
                       "(default: renders of the input at sampled views, i.e. distillation)")
    train.add_argument("--downscale", type=Bounded(int, 1), default=None, metavar="N",
                       help="dataset image downscale factor: %(type)s (default: 1)")
    train.add_argument("--iterations", type=Bounded(int, 0), default=None, metavar="N",
                       help="retraining steps, one view each: %(type)s (default: "
                       f"{RETRAIN_DEFAULTS['iterations']})")
    train.add_argument("--finish-iterations", type=Bounded(int, 0), default=None, metavar="N",
                       help="steps of the quantization-aware finish, 0 = off: %(type)s (default: "
                       f"{RETRAIN_DEFAULTS['finish_iterations']})")
    train.add_argument("--nested", action="store_true", default=None,
                       help="progressive by construction: fix the patch layers before training "
                       "and train every layer prefix (--nested-full-share of the steps the "
                       "whole file, the rest shorter prefixes), so each prefix a streaming viewer "
                       "shows is a trained scene; same steps (default: off)")
    train.add_argument("--nested-full-share", type=Bounded(float, 0, 1), default=None,
                       metavar="F", help="with --nested: the share of the steps that train the "
                       "whole file; lower: better early prefixes, a weaker full file "
                       "(docs/RESULTS.md 15.2): %(type)s (default: "
                       f"{RETRAIN_DEFAULTS['nested_full_share']})")
    train.add_argument("--views", type=Bounded(int, 1, 10000), default=None, metavar="N",
                       help="distillation: training views sampled around the input: %(type)s "
                       f"(default: {RETRAIN_DEFAULTS['views']})")
    train.add_argument("--close-views", type=Bounded(int, 0, 10000), default=None, metavar="N",
                       help="distillation: close-up views (half the distance, trained as crops) "
                       "besides the whole-scene ones: %(type)s, 0 for none (default: "
                       f"{RETRAIN_DEFAULTS['close_views']})")
    train.add_argument("--resolution", type=Bounded(int, 8, 8192), default=None, metavar="PIXELS",
                       help="distillation: side of the square training views: %(type)s "
                       f"(default: {RETRAIN_DEFAULTS['resolution']})")
    p.add_argument("--up", default="-y", choices=["+x", "-x", "+y", "-y", "+z", "-z"],
                   metavar="AXIS", help="the scene's up axis, one of +x -x +y -y +z -z: for "
                   "sampled views (as for eval) and stored in the file for viewers; write a "
                   "negative axis as --up=-y (default: %(default)s)")
    p.add_argument("--antialiased", action="store_true",
                   help="render with Mip-Splatting's antialiased opacity (default: off)")
    p.add_argument("--blur-variance", type=Bounded(float, 0), default=None, metavar="PX2",
                   help="the screen-space low-pass (pixels^2) retraining and pruning render "
                   "with, and with --dataset the test PSNR it reports: 0.075 is PlayCanvas's, "
                   "0.3 INRIA's and gsplat's: %(type)s (default: "
                   f"{VIEWER_BLUR_VARIANCE}, the viewer's, when distilling; "
                   f"{DATASET_BLUR_VARIANCE} with --dataset, the one its images' model "
                   "trained with)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help=DEVICE_HELP)
    p.add_argument("--threads", type=Bounded(int, 1, 1024), default=None, metavar="N",
                       help="CPU threads for rendering and training: %(type)s (default: 1; the CPU "
                       "renderer gains little from more and, on a busy 2-core machine, ran 4-8x "
                       "slower with 2)")
    train.add_argument("--checkpoint-every", type=Bounded(int, 0), default=None, metavar="N",
                       help="rewrite the checkpoint OUTPUT.ckpt every N steps, 0 = only when "
                       f"interrupted: %(type)s (default: {CHECKPOINT_EVERY})")
    train.add_argument("--resume", action="store_true",
                       help="continue an interrupted encode from OUTPUT.ckpt; give the same "
                       "arguments (default: off)")


@command("encode", "encode a 3DGS PLY into an .spc bitstream", _add_encode)
def cmd_encode(args: argparse.Namespace) -> int:
    from .encoder.pipeline import encode
    from .encoder.preview import encode_with_preview
    from .encoder.progress import StageReporter, print_summary
    from .encoder.ratecontrol import parse_size
    from .fileio import atomic_write, check_writable, refuse_same_file
    from .formats import read_scene

    refuse_same_file(args.output, args.input)
    check_writable(args.output)
    if args.stats:
        refuse_same_file(args.stats, args.input, args.output)
        check_writable(args.stats)
    config = encode_config(args)
    preview_size = parse_size(args.preview_size) if args.preview_size is not None else None
    control = run_control(args, config.retrain is not None)
    cloud = read_scene(args.input)  # PLY, compressed.ply, SPZ, .splat, SOG, .ksplat by content
    reporter = StageReporter(enabled=not args.quiet)
    with _stop_on_ctrl_c(control):
        try:
            if preview_size is None:
                result = encode(cloud, config, progress=reporter.stage,
                                source_name=Path(args.input).name, dataset=args.dataset,
                                control=control)
            else:
                result = encode_with_preview(cloud, config, preview_size, reporter.stage,
                                             Path(args.input).name, args.dataset, control)
        except (Interrupted, KeyboardInterrupt):
            reporter.interrupt()
            raise
    atomic_write(args.output, result.data)
    stats = dict(result.stats, input_bytes=os.path.getsize(args.input), output=str(args.output))
    if args.stats:
        atomic_write(args.stats, (json.dumps(stats, indent=2) + "\n").encode())
    print_summary(stats, report_stream(args.output))
    return EXIT_OK


def encode_config(args: argparse.Namespace):
    """The EncoderConfig the encode options describe (checked, with one-line errors)."""
    import dataclasses

    from .encoder.config import EncoderConfig
    from .encoder.presets import preset_config, retrains, sized, with_layers
    from .encoder.ratecontrol import parse_size

    retrain = not args.no_retrain and retrains(args.preset)
    without = "--no-retrain" if args.no_retrain else f"--preset {args.preset} (it never retrains)"
    if not retrain:
        given = [f"--{n.replace('_', '-')}" for n in ("dataset", "iterations", "finish_iterations",
                                                      "views", "close_views", "resolution",
                                                      "resume", "checkpoint_every", "downscale",
                                                      "nested", "nested_full_share")
                 if getattr(args, n) not in (None, False)]
        if given:
            raise UsageError(f"{', '.join(given)} only apply to retraining: drop {without} or "
                             "them")
    targets = [f"--{n.replace('_', '-')}" for n in ("target_size", "target_psnr",
                                                        "patch_downsample")
               if getattr(args, n) is not None]
    if len(targets) > 1:
        raise UsageError(f"{' and '.join(targets)} each choose how many patch Gaussians survive: "
                         "give one of them")
    config = preset_config(args.preset, EncoderConfig(
        seed=args.seed, n_jobs=args.jobs, use_sketch=not args.no_sketch, codec=args.codec,
        gzip=args.gzip), retrain=retrain)
    if args.target_size is not None:
        config = sized(config, parse_size(args.target_size))
    config.target_psnr = args.target_psnr
    config.up, config.antialiased = args.up, args.antialiased
    if args.blur_variance is not None:
        config.blur_variance = args.blur_variance
    if args.nested_full_share is not None and not args.nested:
        raise UsageError("--nested-full-share sets how --nested trains: give --nested too, or "
                         "drop it")
    if args.patch_layers is not None:
        config.patch = with_layers(config.patch, args.patch_layers)
    if args.position_bits is not None:
        config.patch = dataclasses.replace(config.patch, position_bits=args.position_bits)
    if args.tau_max is not None:
        config.refine = dataclasses.replace(config.refine, tau_max=args.tau_max)
    if retrain:
        changes = {}
        for name in ("patch_downsample", "prune", "iterations", "finish_iterations", "views",
                     "close_views", "resolution", "downscale", "nested", "nested_full_share"):
            if getattr(args, name) is not None:
                changes[name] = getattr(args, name)
        config.retrain = dataclasses.replace(config.retrain, **changes)
    elif args.patch_downsample is not None or args.prune is not None:
        raise UsageError(f"--patch-downsample and --prune need retraining, which {without} "
                         "leaves out (give --target-size to prune by importance without it)")
    return config


def run_control(args: argparse.Namespace, retraining: bool):
    """Device and threads of an encode (checked before any work), and for retraining the
    checkpoint and the resume hint."""
    import shlex

    import torch

    from .encoder.retrain import RunControl
    from .imaging.training.checkpoint import checkpoint_path

    torch.set_num_threads(args.threads or DEFAULT_THREADS)
    check_device(args.device)
    if not retraining:
        return RunControl(device=args.device)
    argv = [a for a in sys.argv[1:] if a != "--resume"] + ["--resume"]
    every = CHECKPOINT_EVERY if args.checkpoint_every is None else args.checkpoint_every
    return RunControl(device=args.device, checkpoint=checkpoint_path(args.output),
                      checkpoint_every=every, resume=args.resume,
                      resume_hint="spcodec " + shlex.join(argv))


def check_device(device: str) -> None:
    """Refuse a --device this machine lacks (``cuda`` without a GPU) with a one-line usage
    error, before any work: encode, eval and render share this check."""
    from .imaging.render import resolve_device

    try:
        resolve_device(device)  # before any work: a missing GPU is the user's to fix
    except RuntimeError as exc:
        raise UsageError(f"--device {device}: {exc}; use --device cpu or auto") from None


@contextlib.contextmanager
def _stop_on_ctrl_c(control):
    """While training, the first Ctrl-C asks the loop to stop after its current step (it then
    writes a checkpoint); outside training, or on a second Ctrl-C, it interrupts at once."""
    if control is None or threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        if control.stoppable and not control.stop.is_set():
            control.stop.set()
            print("\nstopping after this step and saving a checkpoint (Ctrl-C again to abort)",
                  file=sys.stderr, flush=True)
        else:
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# ---------------------------------------------------------------------------- eval, render
def load_model(path: str, max_layer: int | None = None):
    """A scene from an .spc (by its magic, gzip-wrapped or not) or from any scene file the
    formats registry reads (PLY, SPZ, .splat, SOG, .ksplat; by content)."""
    from .decoder import decode
    from .formats import read_scene

    if _is_spc(path):
        return decode(path, max_layer=max_layer)
    if max_layer is not None:
        raise UsageError(f"--max-layer needs an .spc input; {path} is not one")
    cloud = read_scene(path)
    try:
        cloud.check_finite()  # what encode refuses, render and eval refuse too
    except FormatError as exc:
        raise FormatError(f"{path}: {exc.args[0]}", exc.code) from None
    return cloud


def _is_spc(path: str) -> bool:
    """An .spc by its magic, gzip-wrapped or not (whatever its name; a gzip-wrapped SPZ is none)."""
    from .formats import HEAD_BYTES, spc

    if os.path.isdir(path):  # an unbundled SOG
        return False
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
    return spc.sniff(head)


def view_up(given: str | None, *paths: str | None) -> str:
    """The up axis of sampled views: ``--up`` when given, else the one the first .spc among
    ``paths`` stores (encode --up records it, as viewers and .glb use it), else -y. Without
    this a z-up scene tumbled sideways unless --up was repeated."""
    from .decoder import inspect

    if given is not None:
        return given
    for path in paths:
        if path is not None and _is_spc(path):
            stored = (inspect(path).metadata or {}).get("up")
            if stored in UP_AXES:  # metadata is untrusted: anything else is ignored
                return stored
    return "-y"


def _add_view_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--resolution", type=Bounded(int, 8, 8192), default=400, metavar="PIXELS",
                   help="side of square sampled views: %(type)s (default: %(default)s)")
    p.add_argument("--max-layer", type=MAX_LAYER, default=None, metavar="K",
                   help="use layers 0..K of an .spc: %(type)s (default: every layer)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help=DEVICE_HELP)
    p.add_argument("--up", default=None, choices=UP_AXES,
                   metavar="AXIS", help="the scene's up axis for sampled views, one of "
                   "+x -x +y -y +z -z; -y suits COLMAP-derived scenes, +z z-up ones; write "
                   "a negative axis as --up=-y (default: the one an .spc stores, else -y)")
    p.add_argument("--antialiased", action="store_true",
                   help="render with Mip-Splatting's antialiased opacity (default: off)")


def _add_eval(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="the model to judge: an .spc or any 3DGS .ply")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--dataset", help="a dataset folder (COLMAP, transforms.json or LLFF): "
                     "compare with its test images (required: this or --reference)")
    ref.add_argument("--reference", help="the original model (.ply or .spc): compare renders at "
                     "held-out sampled views (required: this or --dataset)")
    p.add_argument("--json", action="store_true", help="print a JSON document (default: text)")
    p.add_argument("--views", type=Bounded(int, 1), default=8, metavar="N",
                   help="sampled views, with --reference: %(type)s (default: %(default)s)")
    p.add_argument("--downscale", type=Bounded(int, 1), default=1, metavar="F",
                   help="divide dataset images by F, with --dataset: %(type)s (default: "
                   "%(default)s)")
    p.add_argument("--save-renders", metavar="DIR",
                   help="write 'reference | ours | error' PNGs into DIR, created if missing "
                   "(default: none)")
    p.add_argument("--closeups", type=closeup_list, default=(0.5, 0.25), metavar="F,F",
                   help="with --reference, also judge the same views from closer: each factor "
                   "times the distance, comma-separated in (0, 1), or none (default: 0.5,0.25)")
    p.add_argument("--closeup-resolution", type=Bounded(int, 8, 8192), default=800,
                   metavar="PIXELS", help="side of the close-up views: %(type)s (default: "
                   "%(default)s)")
    p.add_argument("--blur-variance", type=Bounded(float, 0), default=DATASET_BLUR_VARIANCE,
                   metavar="PX2", help="the screen-space low-pass (pixels^2) both sides render "
                   "with: 0.3 is INRIA's, with which published test PSNR is measured, 0.075 "
                   "PlayCanvas's: %(type)s (default: %(default)s)")
    p.add_argument("--no-cache", action="store_true",
                   help="with --reference, render the reference anew instead of reusing its "
                   "renders from the render cache ($XDG_CACHE_HOME/spcodec/renders, else "
                   "~/.cache/spcodec/renders), and store none (default: use the cache)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress display on stderr (default: off)")
    _add_view_options(p)


@command("eval", "measure PSNR/SSIM (and LPIPS when available) against a dataset or a reference",
         _add_eval)
def cmd_eval(args: argparse.Namespace) -> int:
    from .encoder.progress import StageReporter
    from .fileio import check_writable_folder
    from .imaging.cache import default_cache_dir
    from .imaging.evaluate import (
        EvalConfig,
        evaluate_against_dataset,
        evaluate_against_reference,
        freed_memory_kept,
    )

    save = check_writable_folder(args.save_renders) if args.save_renders else None
    check_device(args.device)
    # on stderr (stdout is the report's), for the stages that last over 2 s
    reporter = StageReporter(enabled=not args.quiet, delay=2.0)
    try:
        with freed_memory_kept():  # the renderer's big temporaries: a fifth less CPU time
            model = load_model(args.input, args.max_layer)  # tenths of a second: no stage
            reference = load_model(args.reference) if args.reference else None
            config = EvalConfig(views=args.views, resolution=args.resolution,
                                downscale=args.downscale, device=args.device,
                                up=view_up(args.up, args.input, args.reference),
                                antialiased=args.antialiased, save_renders=save,
                                closeups=args.closeups,
                                closeup_resolution=args.closeup_resolution,
                                blur_variance=args.blur_variance,
                                cache=None if args.no_cache else default_cache_dir(),
                                progress=reporter.stage)
            if args.dataset:
                report = evaluate_against_dataset(model, Path(args.dataset), config)
            else:
                report = evaluate_against_reference(model, reference, config)
    except BaseException:
        reporter.interrupt()  # an error or Ctrl-C starts a line of its own
        raise
    if args.json:
        print(json.dumps(report.to_json(), indent=2, allow_nan=False))
    else:
        print("\n".join(report.summary_lines(args.input)))
    return EXIT_OK


def _add_render(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc or any 3DGS .ply")
    p.add_argument("-o", "--output", required=True, help="the PNG to write")
    p.add_argument("--view", type=Bounded(int, 0), default=0, metavar="K",
                   help="which of the --views sampled views, the same cameras as 'eval "
                   "--views N': an integer in 0..N-1 (default: %(default)s)")
    p.add_argument("--views", type=Bounded(int, 1), default=8, metavar="N",
                   help="size of the view set --view picks from: %(type)s (default: "
                   "%(default)s, as in eval)")
    p.add_argument("--turntable", type=Bounded(int, 1, MAX_TURNTABLE), metavar="N",
                   help="write a contact sheet of N views around the scene instead: %(type)s "
                   "(default: one view)")
    p.add_argument("--background", default="0,0,0",
                   help="r,g,b, each in [0, 1] (default: %(default)s)")
    _add_view_options(p)


@command("render", "render a view (or a turntable contact sheet) of an .spc or .ply to a PNG",
         _add_render)
def cmd_render(args: argparse.Namespace) -> int:
    from .fileio import check_writable
    from .imaging.images import contact_sheet, write_png
    from .imaging.render import GaussianParams, RenderSettings, render_image, resolve_device
    from .imaging.views import sample_views

    if args.turntable is None and args.view >= args.views:
        raise UsageError(f"--view must be in 0..{args.views - 1} (the --views {args.views} "
                         f"sampled views), got {args.view}")
    check_writable(args.output)
    background = _parse_colour(args.background)
    check_device(args.device)
    cloud = load_model(args.input, args.max_layer)
    if len(cloud) == 0:
        raise UsageError(f"{args.input} holds no Gaussians to render")
    count = args.turntable if args.turntable else args.views
    cameras = sample_views(cloud, count, resolution=(args.resolution, args.resolution),
                           split="eval", up=view_up(args.up, args.input))
    settings = RenderSettings(background=background, antialiased=args.antialiased)
    params = GaussianParams.from_cloud(cloud, resolve_device(args.device))
    if args.turntable:
        image = contact_sheet([render_image(params, cam, settings) for cam in cameras])
    else:
        image = render_image(params, cameras[args.view], settings)
    write_png(args.output, image)
    print(f"wrote {args.output} ({image.shape[1]}x{image.shape[0]})")
    return EXIT_OK


def _parse_colour(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise UsageError(f"--background must be three numbers in [0, 1] like 1,1,1; got {text!r}")
    return values


# ----------------------------------------------------------------------------------- main
class _Parser(argparse.ArgumentParser):
    """argparse with the command line's one-line errors instead of a usage dump."""

    def error(self, message: str) -> NoReturn:
        _fail(f"{message} (see '{self.prog} --help')")
        raise SystemExit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered sub-command."""
    from . import __version__

    parser = _Parser(prog="spcodec", description="Sketch&Patch++ codec for 3D "
                     "Gaussian Splatting scenes")
    parser.add_argument("--version", action="version", version=f"spcodec {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks on errors (default: off)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (help_text, configure, handler) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        configure(p)
        p.set_defaults(handler=handler)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``spcodec`` console script."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a bad argument already reported
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warn
            return int(args.handler(args) or EXIT_OK)
    except BrokenPipeError:  # e.g. `spcodec info X.spc | head -3`: the reader has all it wants
        _quiet_broken_pipe()
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        _fail("interrupted")
        return 130
    except Interrupted as exc:
        _fail(str(exc), label="interrupted")
        return 130
    except Exception as exc:  # noqa: BLE001 - the one place that turns errors into one line
        if args.debug:
            raise
        _fail(describe_error(exc, args))
        return EXIT_USAGE if isinstance(exc, UsageError) else EXIT_ERROR


def describe_error(exc: BaseException, args: argparse.Namespace | None = None) -> str:
    """The one-line message for an exception reaching the command line."""
    source = getattr(args, "input", None)
    if isinstance(exc, FormatError):
        message = f"{source}: {exc}" if source and str(source) not in str(exc) else str(exc)
        if isinstance(exc, TruncatedError) and exc.complete_layers:
            last = exc.complete_layers - 1
            message += f"; decode layers 0..{last} with --max-layer {last}"
        return message
    if isinstance(exc, SpcodecError):
        return str(exc)
    if isinstance(exc, FileNotFoundError):
        return f"{exc.filename}: no such file"
    if isinstance(exc, IsADirectoryError):
        return f"{exc.filename}: is a directory"
    if isinstance(exc, PermissionError):
        return f"{exc.filename}: permission denied"
    if isinstance(exc, OSError):
        return f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": ")
    if isinstance(exc, MemoryError):
        return "out of memory"
    if isinstance(exc, ModuleNotFoundError):
        return missing_extra_message(exc.name or "")
    return f"internal error: {exc.__class__.__name__}: {exc} (run with --debug for a traceback)"


def missing_extra_message(module: str) -> str:
    """Which extra installs a missing module."""
    extra = {"torch": "encoder", "sklearn": "encoder", "scipy": "encoder", "tqdm": "encoder",
             "zstandard": "zstd", "gsplat": "gsplat"}.get(module.split(".")[0])
    if extra:
        return f"this command needs '{module}': pip install 'spcodec[{extra}]'"
    return f"missing Python module '{module}'"


def report_stream(output: str):
    """Where a command's report goes: standard error when its output is standard output (``-``,
    or a name such as /dev/stdout for the same file), so the two never mix."""
    from .fileio import is_stdout
    if is_stdout(output):
        return sys.stderr
    try:
        same = os.path.samestat(os.stat(output), os.fstat(sys.stdout.fileno()))
    except (OSError, ValueError, AttributeError):  # no output yet, or stdout is no real file
        same = False
    return sys.stderr if same else sys.stdout


def _fail(message: str, label: str = "error") -> None:
    first = message.strip().splitlines()[0] if message.strip() else "failed"
    print(f"spcodec: {label}: {first}", file=sys.stderr)


def _quiet_broken_pipe() -> None:
    """After the reader of standard output went away: say nothing, and keep Python from
    complaining about the unflushable stream at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no real file descriptor (a test's captured stream)
        pass


def _warn(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` for the command line: one line, no source location."""
    text = str(message).strip().splitlines()
    print(f"spcodec: warning: {text[0] if text else category.__name__}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
