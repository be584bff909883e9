"""``spcodec info``: what an .spc holds (layers, sections, byte ranges), or one line on a scene
file of another tool."""

from __future__ import annotations

import argparse
import json
import os

from .options import EXIT_OK
from .scenes import spc_source

NAME = "info"
HELP = "describe an .spc file: version, layers, sections and their byte ranges"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="an .spc file, or a .glb that 'spcodec embed' wrote")
    p.add_argument("--json", action="store_true", help="print a JSON document (default: text)")
    p.add_argument("--verify", action="store_true",
                   help="also check the CRC-32 of every section, reading the whole file; a "
                   "damaged one fails the command, named by layer and section (default: off, "
                   "only the header is read)")


def run(args: argparse.Namespace) -> int:
    from spcodec.decoder import inspect
    from spcodec.decoder.api import verify_sections

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
    from spcodec import formats

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
    from spcodec.preview import recorded_prefix_psnr

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
