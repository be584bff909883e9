"""``spcodec serve``: the streaming web viewer and a scene on a local HTTP server
(:mod:`.server` does the serving)."""

from __future__ import annotations

import argparse
import sys

from .options import EXIT_OK, PORT, THROTTLE

NAME = "serve"
HELP = "serve the streaming web viewer and an .spc or a tileset (with HTTP range requests)"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="the scene to show at /: an .spc (streamed layer by layer), a "
                   "folder holding a tileset.json (python -m spcodec.tiling's output, streamed "
                   "node by node as the camera looks), or a .ply or .glb (loaded whole, for "
                   "comparison)")
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


def run(args: argparse.Namespace) -> int:
    from .server import make_server, viewer_missing

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
