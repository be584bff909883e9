"""The ``spcodec`` command line.

Every failure ends with one line on stderr (``spcodec: error: ...``) and a non-zero exit code; no
traceback for a bad file or a bad argument (``--debug`` shows one), and no partial output file.
Commands that need the encoder's heavy dependencies import them only when they run, and say which
extra to install when they are missing.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

from .errors import FormatError, SpcodecError, UsageError

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2

Handler = Callable[[argparse.Namespace], int]
Configure = Callable[[argparse.ArgumentParser], None]
COMMANDS: dict[str, tuple[str, Configure, Handler]] = {}


def command(name: str, help_text: str, configure: Configure):
    """Register ``fn(args) -> exit code`` as sub-command ``name``; ``configure`` adds its options."""
    def wrap(fn: Handler) -> Handler:
        COMMANDS[name] = (help_text, configure, fn)
        return fn
    return wrap


# --------------------------------------------------------------------------------- decode
def _add_decode(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file (gzip-wrapped or not), or a prefix of one")
    p.add_argument("-o", "--output", required=True,
                   help="the file to write: a 3DGS PLY (INRIA layout), or with a .glb name a "
                   "binary glTF with KHR_gaussian_splatting")
    p.add_argument("--max-layer", type=int, default=None,
                   help="decode layers 0..K only (0 = the sketch layer alone)")


@command("decode", "decode an .spc file into a 3DGS PLY or a glTF (.glb)", _add_decode)
def cmd_decode(args: argparse.Namespace) -> int:
    from .decoder import decode_layers
    from .fileio import check_writable
    from .gltf import write_glb
    from .ply import write_ply

    suffix = Path(args.output).suffix.lower()
    if suffix == ".gltf":
        raise UsageError(f"cannot write {args.output}: name it .glb (binary glTF); text .gltf with "
                         "a separate buffer is not supported")
    check_writable(args.output)
    start = time.perf_counter()
    result = decode_layers(args.input, max_layer=args.max_layer)
    elapsed = time.perf_counter() - start
    cloud = result.cloud
    (write_glb if suffix == ".glb" else write_ply)(args.output, cloud)
    counts = ", ".join(f"L{layer.index} {len(layer.cloud)}" for layer in result.layers)
    print(f"decoded {len(cloud)} Gaussians ({counts}) in {elapsed * 1000:.0f} ms -> {args.output}")
    return EXIT_OK


# ----------------------------------------------------------------------------------- info
def _add_info(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file")
    p.add_argument("--json", action="store_true", help="print a JSON document")


@command("info", "describe an .spc file: version, layers, sections and their byte ranges",
         _add_info)
def cmd_info(args: argparse.Namespace) -> int:
    from .decoder import inspect

    doc = inspect(args.input).to_json()
    if args.json:
        print(json.dumps(doc, indent=2))
        return EXIT_OK
    print(f"{args.input}: spcodec bitstream v{doc['version']}, {doc['gaussians']} Gaussians, "
          f"SH degree {doc['sh_degree']}, {doc['stored_size']} bytes"
          f"{' (gzip-wrapped)' if doc['gzip'] else ''}")
    print("layers:")
    for layer in doc["layers"]:
        print(f"  L{layer['index']:<3} {layer['kind']:<7} {layer['gaussians']:>10} Gaussians, "
              f"complete at byte {layer['end_offset']}")
    print("sections:")
    for s in doc["sections"]:
        print(f"  #{s['index']:<3} L{s['layer']:<3} {s['type']:<20} {s['codec']:<5} "
              f"offset {s['offset']:>10}  {s['length']:>10} bytes  (raw {s['raw_length']})")
    if doc["metadata"]:
        print("metadata: " + json.dumps(doc["metadata"], sort_keys=True)[:200])
    return EXIT_OK


# ---------------------------------------------------------------------------------- serve
def _add_serve(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="the scene to show at /: an .spc (streamed layer by layer), or a "
                   ".ply or .glb (loaded whole, for comparison)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000; 0 = any free)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--throttle", type=float, metavar="KBPS", default=None,
                   help="send the scene at this many kilobits per second (e.g. 20000 for "
                   "20 Mbit/s), to watch layers arrive as on a slow connection")
    p.add_argument("--log", action="store_true", help="log every request on stderr")


@command("serve", "serve the streaming web viewer and an .spc (with HTTP range requests)",
         _add_serve)
def cmd_serve(args: argparse.Namespace) -> int:
    from .serve import make_server, viewer_missing

    server = make_server([args.input], host=args.host, port=args.port,
                         throttle_kbps=args.throttle, log=args.log)
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
                   help="folder for demo.spc and demo.ply (created if missing)")
    p.add_argument("--seed", type=int, default=0, help="seed of the built-in scene")


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
                        "print [error-code] on stderr (conformance/README.md)")
    p.add_argument("--max-layer-arg", metavar="'--max-layer {k}'",
                   help="what to append to --decoder for a decode of layers 0..k (without it, "
                        "those decodes are not run)")
    p.add_argument("--json", action="store_true", help="print the results as one JSON document")
    p.add_argument("--only", nargs="+", metavar="PATTERN",
                   help="run only the vectors whose id matches a shell-style pattern")
    p.add_argument("--without-zstd", action="store_true",
                   help="the decoder has no zstd support: decodes that need it expect "
                        "codec-unavailable")
    p.add_argument("--timeout", type=float, default=None, metavar="S",
                   help="seconds an external decode may take (default: 60)")
    p.add_argument("--suite", metavar="DIR", help="the suite to run (default: the one installed "
                   "with spcodec)")
    p.add_argument("--generate", metavar="DIR",
                   help="instead of running, regenerate every vector and the manifest into DIR "
                        "(e.g. conformance/ in the repository)")


@command("conformance", "check a decoder against the conformance vectors (or regenerate them)",
         _add_conformance)
def cmd_conformance(args: argparse.Namespace) -> int:
    from .conformance.command import run

    return run(args)


# ---------------------------------------------------------------------------------- encode
def _add_encode(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="a trained 3DGS scene (.ply, INRIA layout or compressed.ply)")
    p.add_argument("-o", "--output", required=True, help="the .spc file to write")
    p.add_argument("--no-retrain", action="store_true",
                   help="encode without retraining the patch Gaussians (required in this version)")
    p.add_argument("--preset", choices=["lowrate", "balanced", "highrate"], default="balanced",
                   help="rate/quality operating point (default: balanced)")
    p.add_argument("--codec", choices=["zlib", "zstd"], default="zlib",
                   help="section codec (zlib: every decoder reads it; zstd: faster to decode)")
    p.add_argument("--gzip", action="store_true", help="wrap the file in gzip")
    p.add_argument("--no-sketch", action="store_true", help="encode every Gaussian as patch")
    p.add_argument("--patch-layers", type=int, default=None, help="number of patch layers")
    p.add_argument("--tau-max", type=float, default=None,
                   help="polynomial-model error threshold of sketch clusters (unitless)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    p.add_argument("--jobs", type=int, default=None, help="worker processes (default: all cores)")
    p.add_argument("--stats", metavar="FILE", help="also write the encode statistics as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress display")


@command("encode", "encode a 3DGS PLY into an .spc bitstream", _add_encode)
def cmd_encode(args: argparse.Namespace) -> int:
    import dataclasses

    from .encoder.pipeline import EncoderConfig, encode
    from .encoder.presets import preset_config
    from .encoder.progress import StageReporter, print_summary
    from .fileio import atomic_write, check_writable
    from .ply import read_ply

    if not args.no_retrain:
        raise UsageError("retraining is not available in this version: pass --no-retrain")
    check_writable(args.output)
    if args.stats:
        check_writable(args.stats)
    config = preset_config(args.preset, EncoderConfig(
        seed=args.seed, n_jobs=args.jobs, use_sketch=not args.no_sketch, codec=args.codec,
        gzip=args.gzip))
    if args.patch_layers is not None:
        _check_positive(patch_layers=args.patch_layers)
        config.patch = dataclasses.replace(config.patch, layers=args.patch_layers)
    if args.tau_max is not None:
        if not args.tau_max > 0:
            raise UsageError(f"--tau-max must be positive, got {args.tau_max}")
        config.refine = dataclasses.replace(config.refine, tau_max=args.tau_max)
    cloud = read_ply(args.input)
    reporter = StageReporter(enabled=not args.quiet)
    result = encode(cloud, config, progress=reporter.stage, source_name=Path(args.input).name)
    atomic_write(args.output, result.data)
    stats = dict(result.stats, input_bytes=os.path.getsize(args.input), output=str(args.output))
    if args.stats:
        atomic_write(args.stats, (json.dumps(stats, indent=2) + "\n").encode())
    print_summary(stats)
    return EXIT_OK


# ---------------------------------------------------------------------------- eval, render
def load_model(path: str, max_layer: int | None = None):
    """A scene from an .spc (by its magic, gzip-wrapped or not) or from any 3DGS PLY."""
    from .container import GZIP_MAGIC, MAGIC
    from .decoder import decode
    from .ply import read_ply

    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
    if head == MAGIC or head[:2] == GZIP_MAGIC:
        return decode(path, max_layer=max_layer)
    if max_layer is not None:
        raise UsageError(f"--max-layer needs an .spc input; {path} is not one")
    return read_ply(path)


def _add_view_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--resolution", type=int, default=400, help="side of square views (pixels)")
    p.add_argument("--max-layer", type=int, default=None, help="use layers 0..K of an .spc")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="auto: gsplat on CUDA when available, else the CPU renderer")
    p.add_argument("--up", default="-y", help="the scene's up axis for sampled views "
                   "(-y suits COLMAP-derived scenes; e.g. +z for z-up scenes)")
    p.add_argument("--antialiased", action="store_true",
                   help="render with Mip-Splatting's antialiased opacity")


def _add_eval(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="the model to judge: an .spc or any 3DGS .ply")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--dataset", help="a dataset folder (COLMAP, transforms.json or LLFF): "
                     "compare with its test images")
    ref.add_argument("--reference", help="the original model (.ply or .spc): compare renders at "
                     "held-out sampled views")
    p.add_argument("--json", action="store_true", help="print a JSON document")
    p.add_argument("--views", type=int, default=8, help="sampled views (with --reference)")
    p.add_argument("--downscale", type=int, default=1, help="dataset image downscale factor")
    p.add_argument("--save-renders", metavar="DIR",
                   help="write 'reference | ours | error' PNGs into DIR")
    _add_view_options(p)


@command("eval", "measure PSNR/SSIM (and LPIPS when available) against a dataset or a reference",
         _add_eval)
def cmd_eval(args: argparse.Namespace) -> int:
    from .encoder.evaluate import (
        EvalConfig,
        evaluate_against_dataset,
        evaluate_against_reference,
    )

    _check_positive(views=args.views, resolution=args.resolution, downscale=args.downscale)
    save = Path(args.save_renders) if args.save_renders else None
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
    config = EvalConfig(views=args.views, resolution=args.resolution, downscale=args.downscale,
                        device=args.device, up=args.up, antialiased=args.antialiased,
                        save_renders=save)
    model = load_model(args.input, args.max_layer)
    if args.dataset:
        report = evaluate_against_dataset(model, Path(args.dataset), config)
    else:
        report = evaluate_against_reference(model, load_model(args.reference), config)
    if args.json:
        print(json.dumps(report.to_json(), indent=2, allow_nan=False))
    else:
        lpips = "n/a (weights not found)" if report.lpips is None else f"{report.lpips:.4f}"
        print(f"{args.input}: PSNR {report.psnr:.2f} dB, SSIM {report.ssim:.4f}, LPIPS {lpips} "
              f"over {len(report.views)} views of {report.width}x{report.height} "
              f"({report.mode}, {report.device}, {report.seconds:.1f} s)")
    return EXIT_OK


def _add_render(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc or any 3DGS .ply")
    p.add_argument("-o", "--output", required=True, help="the PNG to write")
    p.add_argument("--view", type=int, default=0, help="which sampled view (0-based)")
    p.add_argument("--turntable", type=int, metavar="N",
                   help="write a contact sheet of N views around the scene instead")
    p.add_argument("--background", default="0,0,0", help="r,g,b in [0, 1]")
    _add_view_options(p)


@command("render", "render a view (or a turntable contact sheet) of an .spc or .ply to a PNG",
         _add_render)
def cmd_render(args: argparse.Namespace) -> int:
    from .encoder.images import contact_sheet, write_png
    from .encoder.render import GaussianParams, RenderSettings, render_image, resolve_device
    from .encoder.views import sample_views
    from .fileio import check_writable

    check_writable(args.output)
    _check_positive(resolution=args.resolution)
    background = _parse_colour(args.background)
    cloud = load_model(args.input, args.max_layer)
    if len(cloud) == 0:
        raise UsageError(f"{args.input} holds no Gaussians to render")
    count = args.turntable if args.turntable else args.view + 1
    _check_positive(turntable=count)
    cameras = sample_views(cloud, count, resolution=(args.resolution, args.resolution),
                           split="eval", up=args.up)
    settings = RenderSettings(background=background, antialiased=args.antialiased)
    params = GaussianParams.from_cloud(cloud, resolve_device(args.device))
    if args.turntable:
        image = contact_sheet([render_image(params, cam, settings) for cam in cameras])
    else:
        image = render_image(params, cameras[args.view], settings)
    write_png(args.output, image)
    print(f"wrote {args.output} ({image.shape[1]}x{image.shape[0]})")
    return EXIT_OK


def _check_positive(**values: int) -> None:
    for name, value in values.items():
        if value is not None and value < 1:
            raise UsageError(f"--{name.replace('_', '-')} must be at least 1, got {value}")


def _parse_colour(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise UsageError(f"--background must be three numbers in [0, 1] like 1,1,1; got {text!r}")
    return values


# ----------------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered sub-command."""
    from . import __version__

    parser = argparse.ArgumentParser(prog="spcodec", description="Sketch&Patch++ codec for 3D "
                                     "Gaussian Splatting scenes")
    parser.add_argument("--version", action="version", version=f"spcodec {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
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
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or EXIT_OK)
    except KeyboardInterrupt:
        _fail("interrupted")
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
        return f"{source}: {exc}" if source and str(source) not in str(exc) else str(exc)
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


def _fail(message: str) -> None:
    first = message.strip().splitlines()[0] if message.strip() else "failed"
    print(f"spcodec: error: {first}", file=sys.stderr)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
