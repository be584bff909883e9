"""``spcodec conformance``: run the suite against a decoder, or regenerate it.

The options are declared in ``cli/conformance.py``, beside the other commands; this module does the work,
so the command line stays a thin layer over :func:`~.runner.run_suite` and
:func:`~.generate.generate`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from spcodec.errors import UsageError

from .manifest import SUITE_DIR, ManifestError, load_manifest
from .runner import ExternalDecoder, InProcessDecoder, run_suite

EXIT_OK, EXIT_FAILED = 0, 1


def run(args: argparse.Namespace) -> int:
    """The command's handler: exit 0 when every decode passed, 1 when any failed."""
    if args.generate is not None:
        return _generate(Path(args.generate))
    if args.max_layer_arg and not args.decoder:
        raise UsageError("--max-layer-arg needs --decoder (the in-process decoder takes max_layer)")
    if args.timeout is not None and not args.timeout > 0:
        raise UsageError(f"--timeout must be positive, got {args.timeout}")
    try:
        manifest = load_manifest(Path(args.suite).resolve() if args.suite else SUITE_DIR)
    except ManifestError as exc:
        raise UsageError(str(exc)) from None
    if args.decoder:
        decoder = ExternalDecoder(args.decoder, args.max_layer_arg, args.timeout or 60.0)
    else:
        decoder = InProcessDecoder()
    report = run_suite(decoder, manifest, args.only or None, args.without_zstd)
    if not report.results:
        raise UsageError(f"no vector matches {' '.join(args.only)}")
    print(json.dumps(report.to_json(), indent=1) if args.json else report.table())
    return EXIT_OK if report.ok else EXIT_FAILED


def _generate(out: Path) -> int:
    from .generate import generate

    manifest = generate(out)
    kinds = [v.kind for v in manifest.vectors]
    size = sum(p.stat().st_size for p in (out / "vectors").rglob("*") if p.is_file())
    print(f"wrote {len(kinds)} vectors ({kinds.count('valid')} valid, {kinds.count('invalid')} "
          f"invalid, {size / 1024:.0f} KB) and {out / 'manifest.json'}")
    return EXIT_OK
