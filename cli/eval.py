"""``spcodec eval``: PSNR/SSIM (and LPIPS when available) of a scene against a dataset's test
images or against renders of a reference scene."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import scenes
from .options import EXIT_OK, Bounded, add_view_options, check_device, closeup_list, use_threads

NAME = "eval"
HELP = "measure PSNR/SSIM (and LPIPS when available) against a dataset or a reference"


def configure(p: argparse.ArgumentParser) -> None:
    from spcodec.encoder.config import DATASET_BLUR_VARIANCE

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
    add_view_options(p)


def run(args: argparse.Namespace) -> int:
    from spcodec.encoder.progress import StageReporter
    from spcodec.fileio import check_writable_folder
    from spcodec.imaging.cache import default_cache_dir
    from spcodec.imaging.evaluate import (
        EvalConfig,
        evaluate_against_dataset,
        evaluate_against_reference,
        freed_memory_kept,
    )

    save = check_writable_folder(args.save_renders) if args.save_renders else None
    check_device(args.device)
    use_threads(args.threads)
    # on stderr (stdout is the report's), for the stages that last over 2 s
    reporter = StageReporter(enabled=not args.quiet, delay=2.0)
    try:
        with freed_memory_kept():  # the renderer's big temporaries: a fifth less CPU time
            model = scenes.load_model(args.input, args.max_layer)  # tenths of a second: no stage
            reference = scenes.load_model(args.reference) if args.reference else None
            config = EvalConfig(views=args.views, resolution=args.resolution,
                                downscale=args.downscale, device=args.device,
                                up=scenes.view_up(args.up, args.input, args.reference),
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
