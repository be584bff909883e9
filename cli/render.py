"""``spcodec render``: one sampled view, or a turntable contact sheet, of a scene to a PNG.

A contact sheet of many views of a large scene takes tens of seconds on a CPU, so the views are
one progress stage (on stderr, shown only once it has run 2 s, as ``eval``'s are)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from spcodec.errors import UsageError

from . import scenes
from .options import EXIT_OK, Bounded, add_view_options, check_device, use_threads

if TYPE_CHECKING:
    import numpy as np

    from spcodec.encoder.progress import StageReporter
    from spcodec.imaging.cameras import Camera
    from spcodec.imaging.render import GaussianParams, RenderSettings

NAME = "render"
HELP = "render a view (or a turntable contact sheet) of an .spc or .ply to a PNG"

MAX_TURNTABLE = 64
"""Views in a turntable contact sheet (64 views of 400 pixels make a 3,200-pixel square)."""


def configure(p: argparse.ArgumentParser) -> None:
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
    p.add_argument("--quiet", action="store_true",
                   help="no progress display on stderr (default: off)")
    add_view_options(p)


def run(args: argparse.Namespace) -> int:
    from spcodec.encoder.progress import StageReporter
    from spcodec.fileio import check_writable
    from spcodec.imaging.images import contact_sheet, write_png
    from spcodec.imaging.render import GaussianParams, RenderSettings, resolve_device
    from spcodec.imaging.views import sample_views

    if args.turntable is None and args.view >= args.views:
        raise UsageError(f"--view must be in 0..{args.views - 1} (the --views {args.views} "
                         f"sampled views), got {args.view}")
    check_writable(args.output)
    background = _parse_colour(args.background)
    check_device(args.device)
    use_threads(args.threads)
    cloud = scenes.load_model(args.input, args.max_layer)
    if len(cloud) == 0:
        raise UsageError(f"{args.input} holds no Gaussians to render")
    count = args.turntable if args.turntable else args.views
    cameras = sample_views(cloud, count, resolution=(args.resolution, args.resolution),
                           split="eval", up=scenes.view_up(args.up, args.input))
    settings = RenderSettings(background=background, antialiased=args.antialiased)
    params = GaussianParams.from_cloud(cloud, resolve_device(args.device))
    shots = cameras if args.turntable else [cameras[args.view]]
    images = _render_all(params, shots, settings, StageReporter(enabled=not args.quiet, delay=2.0))
    image = contact_sheet(images) if args.turntable else images[0]
    write_png(args.output, image)
    print(f"wrote {args.output} ({image.shape[1]}x{image.shape[0]})")
    return EXIT_OK


def _render_all(params: GaussianParams, cameras: list[Camera], settings: RenderSettings,
                reporter: StageReporter) -> list[np.ndarray]:
    """Render every camera as one progress stage; an error or Ctrl-C ends the stage's line first,
    so the one-line error is not glued to a progress bar."""
    from spcodec.imaging.render import render_image

    first = cameras[0]
    stage = reporter.stage(f"render {len(cameras)} view{'s' if len(cameras) > 1 else ''} of "
                           f"{first.width}x{first.height}", len(cameras))
    try:
        images = []
        for camera in cameras:
            images.append(render_image(params, camera, settings))
            stage.update()
    except BaseException:
        reporter.interrupt()
        raise
    stage.done(f"{len(images)} rendered")
    return images


def _parse_colour(text: str) -> tuple[float, float, float]:
    """``--background``: three numbers in [0, 1], comma-separated."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise UsageError(f"--background must be three numbers in [0, 1] like 1,1,1; got {text!r}")
    return values
