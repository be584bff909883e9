"""Describing a file from its header: what ``spcodec info`` prints (the spec's Annex A).

Only the header block, the metadata and the preview are read, so a client can describe a file,
or the prefix of it that has arrived, without decoding its layers.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

from spcodec.codecs import gunzip, is_gzip, read_gzip_layer_ends
from spcodec.container import Codec, SectionType
from spcodec.errors import FormatError
from spcodec.limits import DEFAULT_LIMITS, Limits

from .api import Source, _complete_layers, _unwrap, read_source
from .header import Header, header_bytes_needed, read_header
from .layers import section_payload
from .preview import find_preview, parse_preview


@dataclass
class FileInfo:
    """A description of a file built from its header (and metadata section)."""

    header: Header
    gzip: bool
    stored_size: int
    """Size of what was read: the whole file, or the prefix that was available."""
    gzip_layer_ends: list[int] | None = None
    metadata: dict | None = None
    metadata_error: str | None = None
    available: int | None = None
    """Bytes of the (inner, inflated) file present; None: all of them (``file_size``)."""
    preview: dict | None = None
    """The preview's takeover layer, extent and size (spec 7.4), or None without one."""

    @property
    def complete_layers(self) -> int:
        """How many leading layers are whole in the data: layers 0..complete_layers-1 decode."""
        return _complete_layers(self.header, self.available_bytes)

    @property
    def available_bytes(self) -> int:
        return self.header.file_size if self.available is None else self.available

    @property
    def truncated(self) -> bool:
        """True when the data ends inside a layer: a plain decode fails, ``max_layer`` helps.

        Data that ends exactly at a layer boundary is a valid prefix ([R-11]), not truncated.
        """
        boundaries = {layer.end_offset for layer in self.header.layers}
        return self.available_bytes < self.header.file_size and \
            self.available_bytes not in boundaries

    def to_json(self) -> dict:
        """The ``spcodec info --json`` document (see the spec's annex on ``info``)."""
        h = self.header
        layers = []
        for layer in h.layers:
            entry = {"index": layer.index, "kind": layer.kind.name.lower(),
                     "gaussians": layer.gaussian_count, "end_offset": layer.end_offset,
                     "complete": layer.end_offset <= self.available_bytes}
            if self.gzip:
                entry["inner_end_offset"] = layer.end_offset
                entry["end_offset"] = (self.gzip_layer_ends[layer.index]
                                       if self.gzip_layer_ends else None)
            layers.append(entry)
        return {
            "version": f"{h.version[0]}.{h.version[1]}",
            "gaussians": h.gaussian_count,
            "sh_degree": h.sh_degree,
            "file_size": h.file_size,
            "header_size": h.header_size,
            "gzip": self.gzip,
            "stored_size": self.stored_size,
            "available_bytes": self.available_bytes,
            "complete_layers": self.complete_layers,
            "truncated": self.truncated,
            "sections": [
                {"index": s.index, "type": s.type_name, "type_id": s.type,
                 "codec": _codec_name(s.codec), "layer": s.layer, "offset": s.offset,
                 "length": s.stored_length, "raw_length": s.raw_length,
                 "crc32": f"{s.crc32:08x}", "required": s.required}
                for s in h.sections
            ],
            "layers": layers,
            "metadata": self.metadata,
            **({"preview": self.preview} if self.preview is not None else {}),
        }


def _codec_name(codec: int) -> str:
    try:
        return Codec(codec).name.lower()
    except ValueError:
        return f"unknown-{codec}"


def inspect(source: Source, limits: Limits | None = None) -> FileInfo:
    """Describe a file from its header, and say which of its layers the data holds whole.

    Of a plain file on disk only the header, metadata and preview are read (its size tells the
    rest); a gzip-wrapped one is inflated whole, since only that tells how much inner data it
    holds.
    """
    limits = limits or DEFAULT_LIMITS
    if isinstance(source, (str, os.PathLike)):
        data = _read_header_prefix(source, limits)
        stored = os.path.getsize(source)
        if is_gzip(data) and len(data) < stored:
            data = read_source(source, limits)
    else:
        data = read_source(source, limits)
        stored = len(data)
    wrapped = is_gzip(data)
    inner, _ = _unwrap(data, limits)
    header = read_header(inner, limits)
    info = FileInfo(header, wrapped, stored, _gzip_layer_ends(data, header) if wrapped else None,
                    available=len(inner) if wrapped else stored)
    meta = header.layers[0].section(SectionType.METADATA)
    if meta is not None and len(inner) >= meta.end:
        try:
            limits.check("metadata length", meta.raw_length, limits.max_metadata_bytes)
            raw = section_payload(inner, meta)
            info.metadata = parse_metadata(raw)
        except FormatError as exc:
            info.metadata_error = str(exc)
    info.preview = _describe_preview(inner, header, limits)
    return info


def _describe_preview(inner: bytes | memoryview, header: Header, limits: Limits) -> dict | None:
    """``info``'s account of the preview (Annex A): None without one; its error, rather than
    an exception, when it does not decode, since the file is valid all the same ([R-103])."""

    try:
        section = find_preview(header)
    except FormatError as exc:
        return {"error": str(exc)}
    if section is None:
        return None
    doc: dict = {"end_offset": section.end}
    if len(inner) < section.end:
        return {**doc, "complete": False}
    try:
        preview = parse_preview(section_payload(inner, section), header, section, limits)
    except FormatError as exc:
        return {**doc, "complete": True, "error": str(exc)}
    return {**doc, "complete": True, "takeover_layer": preview.takeover_layer,
            "bytes": preview.header.file_size, "gaussians": len(preview.cloud)}


def _gzip_layer_ends(data: bytes | memoryview, header: Header) -> list[int] | None:
    """The wrapper's ``SP`` layer offsets ([R-83]), or None when they cannot describe the file.

    The subfield is advisory and decoders may ignore it; one with a count other than the layer
    table's, or offsets that do not increase, is ignored rather than reported (a short list
    used to make ``to_json`` fail with IndexError).
    """
    ends = read_gzip_layer_ends(data)
    if ends is None or len(ends) != len(header.layers) or \
            any(a >= b for a, b in zip(ends, ends[1:])):
        return None
    return ends


def parse_metadata(raw: bytes) -> dict:
    """The metadata section's JSON object ([R-70])."""
    try:
        value = json.loads(raw.decode("utf-8"), parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        # RecursionError: nesting deeper than the interpreter's stack, e.g. "[" * 100000.
        raise FormatError(f"metadata is not UTF-8 JSON ({exc.__class__.__name__})",
                          "bad-metadata") from None
    if not isinstance(value, dict):
        raise FormatError("metadata is not a JSON object", "bad-metadata")
    return value


def _refuse_constant(name: str) -> None:
    """NaN and Infinity are Python's JSON extensions, not RFC 8259 ([R-70])."""
    raise ValueError(f"{name} is not JSON")


def _read_header_prefix(path: str | os.PathLike, limits: Limits) -> bytes:
    """Read growing prefixes of a file until the header block and metadata section are inside."""
    size = os.path.getsize(path)
    want = 1 << 16
    with open(path, "rb") as fh:
        while True:
            fh.seek(0)
            data = fh.read(min(want, size))
            if len(data) >= size:
                return data
            inner = gunzip(data, limits.max_file_bytes).inner if is_gzip(data) else data
            need = header_bytes_needed(inner)
            if need is not None and need <= len(inner):
                try:
                    header = read_header(inner, limits)
                except FormatError:
                    return data  # let inspect() raise the precise error on this prefix
                need = max([sec.end for sec in header.layers[0].sections
                            if sec.type in (SectionType.METADATA, SectionType.PREVIEW)],
                           default=0)
                if need <= len(inner):
                    return data
            if need is not None:
                limits.check("header block", need, limits.max_file_bytes)
            want *= 4
