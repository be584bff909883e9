"""``spcodec encode``: a 3DGS scene to an .spc.

The option defaults --help shows are read from the encoder's configuration (encoder/config.py and
the presets) when the parser is built, so the two cannot drift apart; which option combinations
make sense is :func:`spcodec.encoder.presets.check_options`'s to say, for library callers too.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import threading
from pathlib import Path

from spcodec.errors import Interrupted, UsageError
from spcodec.limits import DEFAULT_LIMITS

from .options import (
    DEVICE_HELP,
    EXIT_OK,
    SEED,
    THREADS_HELP,
    Bounded,
    check_device,
    report_stream,
    use_threads,
)

NAME = "encode"
HELP = "encode a 3DGS PLY into an .spc bitstream"

CHECKPOINT_EVERY = 500
"""``RunControl.checkpoint_every``, shown by --help (an encode without --checkpoint-every takes
RunControl's own): it lives in encoder/retraining/control.py, which imports torch, and reading it
from there would load torch for every command (a test keeps the two equal)."""


def configure(p: argparse.ArgumentParser) -> None:
    from spcodec.encoder import config
    from spcodec.encoder.presets import PRESETS

    patch, retrain = config.PatchConfig(), config.RetrainConfig()
    shares = [f"{share * 100:g}" for share in patch.layer_fractions]
    downsample = ", ".join(f"{name} {values['retrain']['patch_downsample']:g}"
                           for name, values in PRESETS.items() if values["retrain"] is not None)
    p.add_argument("input", help="a trained 3DGS scene: a PLY (INRIA layout or compressed.ply), "
                   "SPZ, antimatter15 .splat, PlayCanvas SOG (.sog or its folder) or .ksplat, "
                   "recognized by content")
    p.add_argument("-o", "--output", required=True, help="the .spc file to write")
    p.add_argument("--preset", choices=list(PRESETS), default="balanced",
                   help="rate/quality operating point: codebooks, sketch threshold and patch "
                   "downsample; with --no-retrain the codebooks only set the bytes, which the "
                   "precision search spends, without a sketch; transparent keeps every Gaussian, "
                   "never retrains, and aims to look like the input in a viewer (default: "
                   "%(default)s)")
    p.add_argument("--codec", choices=["zlib", "zstd"], default="zlib",
                   help="section codec; zlib: every decoder reads it and the Python one "
                   "fastest, zstd: optional, each frame checked against spec 1.1.1's rules "
                   "(default: %(default)s)")
    p.add_argument("--gzip", action="store_true", help="wrap the file in gzip (default: off)")
    p.add_argument("--no-sketch", action="store_true",
                   help="encode every Gaussian as patch (default: off)")
    p.add_argument("--patch-layers", type=Bounded(int, 1, DEFAULT_LIMITS.max_layers - 1),
                   default=None, metavar="N",
                   help="number of patch layers: %(type)s; each holds "
                   f"{config.LAYER_RATIO:g} times the Gaussians of the one before, except that "
                   f"{patch.layers} hold {', '.join(shares[:-1])} and {shares[-1]} %% of the "
                   f"patch (default: {config.RETRAINED_PATCH_LAYERS} when retraining, "
                   f"{patch.layers} with --no-retrain)")
    p.add_argument("--position-bits", type=Bounded(int, 8, 30), default=None, metavar="B",
                   help="bits of precision of the patch positions over each layer's box: "
                   f"%(type)s (default: {config.RETRAINED_POSITION_BITS} of the scene's extent "
                   f"when retraining, {config.DEFAULT_POSITION_BITS} without, "
                   f"{PRESETS['transparent']['position_bits']} for --preset transparent; "
                   "without retraining the other presets and the targets choose them by rate "
                   "and distortion unless given)")
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
    p.add_argument("--no-eval", action="store_true",
                   help="skip the closing evaluation of a retrained or --target-psnr encode "
                   "(the file against the input at held-out views and close-ups, a minute or "
                   "more): the stats then carry no quality, and `spcodec eval OUTPUT --reference "
                   "INPUT` measures it later (default: off)")

    size = p.add_argument_group("size")
    size.add_argument("--target-size", metavar="SIZE",
                      help="a file of at most SIZE bytes: 150k, 2MB, 300000 (k, M "
                      "decimal; KiB, MiB binary); sets how many patch Gaussians survive pruning "
                      f"and, below {patch.codebook_size * config.TARGET_GROUPS_PER_ENTRY:,} of "
                      "them, shrinks the codebooks to match; with "
                      "--no-retrain, chooses each attribute's codebook and the position grid by "
                      "rate and predicted distortion: above the preset's file for every "
                      "Gaussian; below it, whichever renders closest of every Gaussian coarser, "
                      "fewer at a precision between, or the preset's precision pruned "
                      "(default: none, the preset's downsample)")
    size.add_argument("--target-psnr", type=Bounded(float, 10, 100), metavar="DB",
                      help="the smallest file whose close-up (eval's views at half the distance, "
                      "800x800) reaches DB against the input: %(type)s; sets how many patch "
                      "Gaussians survive and, with --no-retrain, the precision of each attribute "
                      "too (default: none)")
    size.add_argument("--preview-size", metavar="SIZE",
                      help="embed a preview of at most SIZE bytes (spec 7.4): the scene encoded "
                      "a second time for that size, which viewers show until the file's own "
                      "layers beat it; with --target-size the whole file stays within the "
                      "target. Pays on scenes whose quality falls slowly with size "
                      "(docs/LOG.md 15.8); doubles the encode time (default: none)")
    size.add_argument("--patch-downsample", type=Bounded(float, 1), metavar="N",
                      help="keep 1/N of the patch Gaussians: %(type)s (default: set by --preset: "
                      f"{downsample})")
    size.add_argument("--prune", choices=["importance", "sampled", "uniform"], default=None,
                      help="which patch Gaussians survive: the largest blend weight over the "
                      "training views, a random sample in proportion to it, or uniformly at "
                      f"random as in the paper (default: {retrain.prune})")

    train = p.add_argument_group("retraining")
    train.add_argument("--no-retrain", action="store_true",
                       help="skip retraining: code the patch without training; seconds "
                       "instead of minutes, larger files (default: off)")
    train.add_argument("--dataset", metavar="DIR", help="retrain against this dataset's training "
                       "images (COLMAP, transforms.json or LLFF; its test split is held out) "
                       "(default: renders of the input at sampled views, i.e. distillation)")
    train.add_argument("--downscale", type=Bounded(int, 1), default=None, metavar="N",
                       help="dataset image downscale factor: %(type)s (default: "
                       f"{retrain.downscale})")
    train.add_argument("--iterations", type=Bounded(int, 0), default=None, metavar="N",
                       help="retraining steps, one view each: %(type)s (default: "
                       f"{retrain.iterations})")
    train.add_argument("--finish-iterations", type=Bounded(int, 0), default=None, metavar="N",
                       help="steps of the quantization-aware finish, 0 = off: %(type)s (default: "
                       f"{retrain.finish_iterations})")
    train.add_argument("--nested", action="store_true", default=None,
                       help="progressive by construction: fix the patch layers before training "
                       "and train every layer prefix (--nested-full-share of the steps the "
                       "whole file, the rest shorter prefixes), so each prefix a streaming viewer "
                       "shows is a trained scene; same steps (default: off)")
    train.add_argument("--nested-full-share", type=Bounded(float, 0, 1), default=None,
                       metavar="F", help="with --nested: the share of the steps that train the "
                       "whole file; lower: better early prefixes, a weaker full file "
                       "(docs/LOG.md 15.2): %(type)s (default: "
                       f"{retrain.nested_full_share})")
    train.add_argument("--views", type=Bounded(int, 1, 10000), default=None, metavar="N",
                       help="distillation: training views sampled around the input: %(type)s "
                       f"(default: {retrain.views})")
    train.add_argument("--close-views", type=Bounded(int, 0, 10000), default=None, metavar="N",
                       help="distillation: close-up views (half the distance, trained as crops) "
                       "besides the whole-scene ones: %(type)s, 0 for none (default: "
                       f"{retrain.close_views})")
    train.add_argument("--resolution", type=Bounded(int, 8, 8192), default=None, metavar="PIXELS",
                       help="distillation: side of the square training views: %(type)s "
                       f"(default: {retrain.resolution})")
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
                   f"{config.VIEWER_BLUR_VARIANCE}, the viewer's, when distilling; "
                   f"{config.DATASET_BLUR_VARIANCE} with --dataset, the one its images' model "
                   "trained with)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help=DEVICE_HELP)
    p.add_argument("--threads", type=Bounded(int, 1, 1024), default=None, metavar="N",
                   help=THREADS_HELP)
    train.add_argument("--checkpoint-every", type=Bounded(int, 0), default=None, metavar="N",
                       help="rewrite the checkpoint OUTPUT.ckpt every N steps, 0 = only when "
                       f"interrupted: %(type)s (default: {CHECKPOINT_EVERY})")
    train.add_argument("--resume", action="store_true",
                       help="continue an interrupted encode from OUTPUT.ckpt; give the same "
                       "arguments (default: off)")


def run(args: argparse.Namespace) -> int:
    from spcodec.encoder.pipeline import encode
    from spcodec.encoder.preview import encode_with_preview
    from spcodec.encoder.progress import StageReporter, print_summary
    from spcodec.encoder.ratecontrol import parse_size
    from spcodec.fileio import atomic_write, check_writable, refuse_same_file
    from spcodec.formats import read_scene

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
    stats = dict(result.stats.to_json(), input_bytes=os.path.getsize(args.input),
                 output=str(args.output))
    skipped = result.stats.evaluation
    if skipped is not None:  # how to measure it later
        stats["evaluation"] = dict(skipped.to_json(),
                                   command=eval_command(args, skipped.eval_options))
    if args.stats:
        atomic_write(args.stats, (json.dumps(stats, indent=2) + "\n").encode())
    print_summary(stats, report_stream(args.output))
    return EXIT_OK


def eval_command(args: argparse.Namespace, options: list[str]) -> str:
    """The ``spcodec eval`` command that measures what an encode without --no-eval reports."""
    import shlex

    judged = options if args.dataset is not None else ["--reference", str(args.input), *options]
    return shlex.join(["spcodec", "eval", str(args.output), *judged])


def encode_config(args: argparse.Namespace):
    """The EncoderConfig the encode options describe (checked, with one-line errors)."""
    import dataclasses

    from spcodec.encoder.config import EncoderConfig
    from spcodec.encoder.presets import (
        ENCODE_OPTIONS,
        aimed,
        check_options,
        preset_config,
        sized,
        with_layers,
    )
    from spcodec.encoder.ratecontrol import parse_size

    try:
        retrain = check_options(args.preset, **{name: getattr(args, name) for name in ENCODE_OPTIONS})
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    config = preset_config(args.preset, EncoderConfig(
        seed=args.seed, n_jobs=args.jobs, use_sketch=not args.no_sketch, codec=args.codec,
        gzip=args.gzip), retrain=retrain,
        point=args.target_size is None and args.target_psnr is None)
    if args.target_size is not None:
        config = sized(config, parse_size(args.target_size))
    if args.target_psnr is not None:
        config = aimed(config, args.target_psnr)
    config.up, config.antialiased = args.up, args.antialiased
    config.evaluate = not args.no_eval
    if args.blur_variance is not None:
        config.blur_variance = args.blur_variance
    if args.patch_layers is not None:
        config.patch = with_layers(config.patch, args.patch_layers)
    if args.position_bits is not None:
        config.patch = dataclasses.replace(config.patch, position_bits=args.position_bits)
        if config.allocation is not None:  # the precision search keeps the grid asked for
            config.allocation = dataclasses.replace(config.allocation, position_bits=())
    if args.tau_max is not None:
        if not config.use_sketch:
            raise UsageError("--tau-max sets the sketch's clusters, which this encode does not "
                             "build (--no-sketch, or a no-retrain preset without a target: "
                             "DECISIONS D-33): drop --tau-max")
        config.refine = dataclasses.replace(config.refine, tau_max=args.tau_max)
    if retrain:
        changes = {}
        for name in ("patch_downsample", "prune", "iterations", "finish_iterations", "views",
                     "close_views", "resolution", "downscale", "nested", "nested_full_share"):
            if getattr(args, name) is not None:
                changes[name] = getattr(args, name)
        config.retrain = dataclasses.replace(config.retrain, **changes)
    return config


def run_control(args: argparse.Namespace, retraining: bool):
    """Device and threads of an encode (checked before any work), and for retraining the
    checkpoint and the resume hint."""
    import shlex

    from spcodec.encoder.retraining.control import RunControl
    from spcodec.imaging.training.checkpoint import checkpoint_path

    use_threads(args.threads)
    check_device(args.device)
    if not retraining:
        return RunControl(device=args.device)
    argv = [a for a in sys.argv[1:] if a != "--resume"] + ["--resume"]
    every = {} if args.checkpoint_every is None else {"checkpoint_every": args.checkpoint_every}
    return RunControl(device=args.device, checkpoint=checkpoint_path(args.output),
                      resume=args.resume, resume_hint="spcodec " + shlex.join(argv), **every)


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
