"""Embedding a preview in a file (spec 7.4): the writer's side of ``PREVIEW``.

:func:`attach_preview` takes two finished files, the scene and a small file made for a fraction of
the bytes, and lays the second into the first's layer 0, before its sketch, so that it arrives
first. The scene's own sections are carried over byte for byte: only the header block changes,
so the scene decodes to exactly the same Gaussians, and every prefix with it ([R-102]).
"""

from __future__ import annotations

import math

from .codecs import gunzip, is_gzip
from .container import Codec, SectionType
from .decoder import Header, decode_layers, read_header
from .errors import UsageError
from .limits import DEFAULT_LIMITS
from .writer import LayerSpec, Preview, SectionSpec, WrittenFile, assemble_file, gzip_file


def attach_preview(scene: bytes, preview: bytes, takeover_layer: int,
                   gzip: bool | None = None) -> bytes:
    """``scene`` with ``preview`` embedded, shown until layers ``0..takeover_layer`` arrive.

    Both inputs are whole files (gzip-wrapped or not); the preview is stored unwrapped, since a
    PREVIEW section holds a plain file. The result is gzip-wrapped when ``gzip`` says so, or,
    with None, when ``scene`` was. A scene that already has a preview has it replaced.
    """
    return attach_preview_file(scene, preview, takeover_layer, gzip).data


def attach_preview_file(scene: bytes, preview: bytes, takeover_layer: int,
                        gzip: bool | None = None) -> WrittenFile:
    """:func:`attach_preview` with the layout of the file it makes."""
    wrapped = is_gzip(scene)
    inner, small = _whole_file(scene, "the scene"), _whole_file(preview, "the preview")
    header = read_header(inner, DEFAULT_LIMITS)
    # a preview that does not decode is refused before anything is written
    small_header = decode_layers(small).header
    if any(sec.type == SectionType.PREVIEW for sec in small_header.sections):
        # in any layer: refuses an embedded file with a PREVIEW section anywhere
        raise UsageError("the preview has a preview of its own; a preview cannot nest")
    if not 0 <= takeover_layer < len(header.layers):
        raise UsageError(f"takeover layer {takeover_layer} is not a layer of the scene "
                         f"(layers 0..{len(header.layers) - 1})")
    sections = _carried_sections(inner, header)
    at = next((i for i, s in enumerate(sections) if s.type != SectionType.METADATA), 0)
    sections.insert(at, SectionSpec(SectionType.PREVIEW, 0, Preview(small, takeover_layer).payload(),
                                    Codec.NONE, required=False))
    layers = [LayerSpec(layer.kind, layer.gaussian_count) for layer in header.layers]
    written = assemble_file(sections, layers, header.sh_degree)
    return gzip_file(written) if (wrapped if gzip is None else gzip) else written


def choose_takeover(prefix_psnr: list[dict] | None, layer_count: int,
                    preview_psnr: float | None) -> int:
    """The first layer whose prefix scores at least the preview ([R-104]): ``prefix_psnr`` holds
    ``{"layer": K, "psnr": dB}`` per prefix, as retrained files record it in their metadata
    (``stats.prefix_psnr``). The last layer when no prefix does, or when either score is
    unknown: the preview then shows until the whole file is in."""
    last = layer_count - 1
    if preview_psnr is None:
        return last
    for entry in prefix_psnr or []:
        if entry["psnr"] >= preview_psnr:
            return min(int(entry["layer"]), last)
    return last


def recorded_prefix_psnr(metadata: dict | None) -> list[dict]:
    """The per-prefix PSNR a file's metadata records (``stats.prefix_psnr``), leaving out
    malformed entries: metadata is untrusted."""
    stats = metadata.get("stats") if isinstance(metadata, dict) else None
    table = stats.get("prefix_psnr") if isinstance(stats, dict) else None
    if not isinstance(table, list):
        return []
    return [{"layer": e["layer"], "psnr": float(e["psnr"])} for e in table
            if isinstance(e, dict) and type(e.get("layer")) is int
            and type(e.get("psnr")) in (int, float) and math.isfinite(e["psnr"])]


def _whole_file(data: bytes, what: str) -> bytes:
    """The inner file of a whole, possibly gzip-wrapped, input; a prefix is refused."""
    inner = bytes(gunzip(data, DEFAULT_LIMITS.max_file_bytes).inner) if is_gzip(data) \
        else bytes(data)
    if read_header(inner, DEFAULT_LIMITS).file_size != len(inner):
        raise UsageError(f"{what} is a prefix of a file, not a whole file")
    return inner


def _carried_sections(inner: bytes, header: Header) -> list[SectionSpec]:
    """The scene's sections as they are stored (codec, bytes and all), less any old preview."""
    carried = []
    for sec in header.sections:
        if sec.type == SectionType.PREVIEW and sec.layer == 0:
            continue
        stored = inner[sec.offset:sec.end]
        carried.append(SectionSpec(sec.type, sec.layer, b"", sec.codec, required=sec.required,
                                   stored=stored, raw_length=sec.raw_length))
    return carried
