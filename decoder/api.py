"""Public decoding API: whole files, prefixes, and an incremental stream decoder.

``decode`` reads a complete file or a prefix of one; :class:`StreamDecoder` is fed bytes as they
arrive and hands back each layer as soon as its last byte is in, which is what a streaming viewer
needs. Describing a file from its header is :mod:`.info`, its preview :mod:`.preview`.
"""

from __future__ import annotations

import os
import zlib
from dataclasses import dataclass, field
from typing import BinaryIO, Union

from spcodec.cloud import GaussianCloud
from spcodec.codecs import Gunzipped, crc32, gunzip, gunzip_head, is_gzip
from spcodec.container import FIXED_HEADER_SIZE, GZIP_MAGIC, MAGIC, header_size
from spcodec.errors import ChecksumError, FormatError, LimitError, TruncatedError, UsageError
from spcodec.limits import DEFAULT_LIMITS, Limits
from spcodec.sections import IndexContext

from .header import Header, header_bytes_needed, read_header
from .layers import (
    PatchPlan,
    Payloads,
    SketchPlan,
    fill_patch_layer,
    fill_sketch_layer,
    load_layer,
    prepare_patch_layer,
    prepare_sketch_layer,
    read_codebooks,
    read_index_contexts,
)

Source = Union[str, os.PathLike, bytes, bytearray, memoryview, BinaryIO]


@dataclass
class DecodedLayer:
    """One decoded layer."""

    index: int
    kind: str
    cloud: GaussianCloud
    end_offset: int


@dataclass
class DecodeResult:
    """What :func:`decode_layers` returns: the layers, and the header they came from."""

    header: Header
    layers: list[DecodedLayer]
    complete: bool
    """True when every layer the file declares was decoded."""
    cloud: GaussianCloud
    """All decoded layers, layer 0 first (each layer's cloud is a view of this one)."""


class _LayerDecoder:
    """Decodes layers of one file in order, keeping the codebooks and index contexts that
    layer 1 carries.

    Each layer is first *prepared* (CRC-checked, inflated, parsed, Draco-decoded) and only then
    given output memory, so the output is sized by data that exists rather than by a count the
    layer table claims ([R-60], [R-62]).
    """

    def __init__(self, header: Header, limits: Limits) -> None:
        self.header, self.limits, self.codebooks = header, limits, None
        self.contexts: list[IndexContext] = []

    def load(self, data: bytes | memoryview, index: int) -> Payloads:
        """Decoding step 7 for layer ``index``: CRC-check and inflate its sections."""
        return load_layer(data, self.header.layers[index], self.limits)

    def prepare(self, payloads: Payloads, index: int) -> SketchPlan | PatchPlan:
        """Steps 8-9 for a loaded layer, short of allocating its output."""
        if index == 0:
            return prepare_sketch_layer(payloads, self.header, self.limits)
        if self.codebooks is None:
            self.codebooks = read_codebooks(payloads, self.header)
            self.contexts = read_index_contexts(payloads, self.codebooks)
        return prepare_patch_layer(payloads, self.header, index, self.codebooks, self.contexts)

    def fill(self, plan: SketchPlan | PatchPlan, index: int,
             out: GaussianCloud | None = None) -> DecodedLayer:
        """Decode a prepared layer into ``out`` (views of a larger cloud) or a new cloud."""
        layer = self.header.layers[index]
        if out is None:
            out = GaussianCloud.zeros(plan.gaussian_count, self.header.sh_degree)
        if index == 0:
            fill_sketch_layer(plan, out)
        else:
            fill_patch_layer(plan, self.codebooks, out)
        return DecodedLayer(index, layer.kind.name.lower(), out, layer.end_offset)

    def decode(self, data: bytes | memoryview, index: int) -> DecodedLayer:
        """Load, prepare and decode layer ``index`` into a new cloud."""
        return self.fill(self.prepare(self.load(data, index), index), index)


# ------------------------------------------------------------------------------ whole files
def decode(source: Source, max_layer: int | None = None,
           limits: Limits | None = None) -> GaussianCloud:
    """Decode a file (path, bytes or binary file object) or a prefix of one into Gaussians.

    ``max_layer=k`` decodes layers 0..k and needs only the bytes up to that layer's end. With
    ``max_layer=None`` every layer is decoded; data that ends exactly at a layer boundary decodes to
    the layers before it (the prefix property, [R-11]), data that ends anywhere else raises
    :class:`~spcodec.TruncatedError`.
    """
    return decode_layers(source, max_layer, limits).cloud


def decode_layers(source: Source, max_layer: int | None = None,
                  limits: Limits | None = None) -> DecodeResult:
    """Like :func:`decode`, but keeps the layers apart and returns the parsed header."""
    limits = limits or DEFAULT_LIMITS
    if max_layer is not None and max_layer < 0:
        raise UsageError(f"max_layer must be >= 0, got {max_layer}")
    data, _ = _unwrap(read_source(source, limits), limits)
    header = read_header(data, limits)
    last = _last_decodable_layer(header, len(data), max_layer)
    decoder = _LayerDecoder(header, limits)
    # Step 7 for every layer, then steps 8-9 (the order in which the spec reports errors), then
    # one allocation for all layers, sized by what the validated payloads hold; each layer
    # decodes into a view of it.
    payloads = [decoder.load(data, k) for k in range(last + 1)]
    plans = [decoder.prepare(payloads[k], k) for k in range(last + 1)]
    del payloads
    cloud = GaussianCloud.zeros(sum(plan.gaussian_count for plan in plans), header.sh_degree)
    layers, start = [], 0
    for k, plan in enumerate(plans):
        stop = start + plan.gaussian_count
        layers.append(decoder.fill(plan, k, cloud.view(start, stop)))
        start = stop
    return DecodeResult(header, layers, last == len(header.layers) - 1, cloud)


def verify_sections(source: Source, limits: Limits | None = None) -> int:
    """Check the CRC-32 of every section the table lists ([R-7]), decoding nothing; returns how
    many were checked. ``inspect`` reads the header alone, so a damaged layer went unseen until a
    full decode; here one ChecksumError names every damaged section by layer and index, and a
    TruncatedError says which sections the data lacks (they could not be verified)."""
    limits = limits or DEFAULT_LIMITS
    data, _ = _unwrap(read_source(source, limits), limits)
    header = read_header(data, limits)
    view = memoryview(data)
    damaged = [s for s in header.sections
               if s.end <= len(data) and crc32(view[s.offset:s.end]) != s.crc32]
    if damaged:
        raise ChecksumError("CRC-32 mismatch in " + "; ".join(
            f"layer {s.layer} section #{s.index} ({s.type_name}, bytes {s.offset}..{s.end})"
            for s in damaged))
    missing = [s for s in header.sections if s.end > len(data)]
    if missing:
        present = len(header.sections) - len(missing)
        raise TruncatedError(f"the data ends at byte {len(data)} of {header.file_size}: "
                             f"{len(missing)} sections, from layer {min(s.layer for s in missing)} "
                             f"on, are missing or cut short (the {present} present verified)")
    return len(header.sections)


def _last_decodable_layer(header: Header, available: int, max_layer: int | None) -> int:
    """Index of the last layer to decode from ``available`` bytes ([R-11], [R-12])."""
    if available > header.file_size:
        raise FormatError(f"{available - header.file_size} bytes follow the last section",
                          "trailing-data")
    last = len(header.layers) - 1
    target = last if max_layer is None else min(max_layer, last)
    if available >= header.layers[target].end_offset:
        return target
    if max_layer is None:
        for k in range(last - 1, -1, -1):
            if header.layers[k].end_offset == available:
                return k
    complete = _complete_layers(header, available)
    whole = f"; layers 0..{complete - 1} are complete" if complete else "; no layer is complete"
    raise TruncatedError(f"the data ends at byte {available}, inside layer "
                         f"{_layer_at(header, available)} (layer boundaries: "
                         f"{[layer.end_offset for layer in header.layers]}){whole}",
                         complete_layers=complete)


def _complete_layers(header: Header, available: int) -> int:
    """How many leading layers lie whole within the first ``available`` bytes."""
    return sum(layer.end_offset <= available for layer in header.layers)


def _layer_at(header: Header, offset: int) -> int:
    for layer in header.layers:
        if offset < layer.end_offset:
            return layer.index
    return len(header.layers) - 1


def read_source(source: Source, limits: Limits) -> bytes | memoryview:
    """The bytes of a path, a bytes-like object or a binary file, refusing oversized inputs."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        return source
    if isinstance(source, (str, os.PathLike)):
        size = os.path.getsize(source)
        limits.check("input file size", size, limits.max_file_bytes)
        with open(source, "rb") as fh:
            return fh.read()
    if hasattr(source, "read"):
        return _read_stream(source, limits)
    raise UsageError(f"cannot decode from a {type(source).__name__}; pass a path, bytes or a "
                     f"binary file")


_READ_CHUNK = 1 << 24


def _read_stream(source: BinaryIO, limits: Limits) -> bytes:
    """Read a binary file object in chunks, refusing more than ``max_file_bytes``.

    One ``read(max_file_bytes + 1)`` makes a buffered file allocate that many bytes up front
    (4 GiB by default): MemoryError under an address-space limit, for any file, however small.
    """
    parts, total = [], 0
    while True:
        block = source.read(min(_READ_CHUNK, limits.max_file_bytes + 1 - total))
        if not block:
            return b"".join(parts)
        parts.append(block)
        total += len(block)
        limits.check("input size", total, limits.max_file_bytes)


def _unwrap(data: bytes | memoryview, limits: Limits) -> tuple[bytes | memoryview, Gunzipped | None]:
    if is_gzip(data):
        cap = _wrapped_file_size(data, limits)
        try:
            gz = gunzip(data, cap)
        except LimitError:
            if cap < limits.max_file_bytes:
                raise FormatError(f"the gzip wrapper inflates past the inner file's file_size of "
                                  f"{cap} bytes", "trailing-data") from None
            raise
        return gz.inner, gz
    if len(data) < 2 and GZIP_MAGIC.startswith(bytes(data)) and len(data):
        raise TruncatedError("the data ends inside the gzip header")
    return data, None


def _wrapped_file_size(data: bytes | memoryview, limits: Limits) -> int:
    """How much a gzip wrapper may inflate to: the wrapped header's ``file_size`` ([R-84]).

    Only the header block is inflated for this. Without it, a few MB of gzip inflate to the
    4 GiB limit before the decoder looks at the first byte: a bomb of garbage, or a small
    valid file followed by gigabytes of zeros. A header block that is present and invalid is
    reported at once (as the stream decoder does); one that is incomplete means the whole
    wrapper inflates to less than a header, and the limit applies.
    """
    head = gunzip_head(data, header_size(limits.max_layers, limits.max_sections))
    try:
        return read_header(head, limits).file_size
    except TruncatedError:
        return limits.max_file_bytes


# ------------------------------------------------------------------------------ streaming
_PIECE = 1 << 20
@dataclass
class StreamDecoder:
    """Incremental decoder: ``feed`` bytes as they arrive, get layers as they complete.

    >>> dec = StreamDecoder()
    >>> for chunk in chunks:                      # doctest: +SKIP
    ...     for layer in dec.feed(chunk):
    ...         show(layer.cloud)
    >>> dec.close()                                # doctest: +SKIP

    gzip-wrapped input is inflated on the fly. ``close()`` raises :class:`TruncatedError` when the
    data stopped inside a layer (stopping at a layer boundary is a valid prefix).
    """

    limits: Limits = field(default_factory=lambda: DEFAULT_LIMITS)
    max_layer: int | None = None
    header: Header | None = None
    _buffer: bytearray = field(default_factory=bytearray)
    _inflater: object = None
    _started: bool = False
    _next_layer: int = 0
    _decoder: _LayerDecoder | None = None

    def __post_init__(self) -> None:
        if self.max_layer is not None and self.max_layer < 0:
            raise UsageError(f"max_layer must be >= 0, got {self.max_layer}")

    def feed(self, chunk: bytes) -> list[DecodedLayer]:
        """Add bytes; return the layers completed by them (possibly none)."""
        if not self._started:
            self._buffer += chunk
            if len(self._buffer) < 2:
                if self._buffer and self._buffer[:1] not in (MAGIC[:1], GZIP_MAGIC[:1]):
                    raise FormatError("not an spcodec file (bad magic)", "bad-magic")
                return []
            self._started = True
            pending, self._buffer = bytes(self._buffer), bytearray()
            if pending[:2] == GZIP_MAGIC:
                self._inflater = zlib.decompressobj(wbits=31)
            chunk = pending
        self._append(chunk)
        return self._drain()

    def _append(self, chunk: bytes) -> None:
        if self._inflater is None:
            self._buffer += chunk
        else:
            self._inflate(chunk)
        self.limits.check("input size", len(self._buffer), self.limits.max_file_bytes)

    def _inflate(self, chunk: bytes) -> None:
        """Inflate a piece of the gzip wrapper, at most 1 MiB at a time, so that as soon as the
        inner header block is whole its ``file_size`` caps the output ([R-84]): a small chunk of
        a gzip bomb stops there instead of at the 4 GiB limit."""
        while True:
            self._read_header_if_ready()
            cap = self.limits.max_file_bytes if self.header is None else self.header.file_size
            if len(self._buffer) > cap:
                if self.header is None:
                    raise LimitError("gzip wrapper inflates past the file size limit")
                raise FormatError("the gzip wrapper inflates past the inner file's file_size",
                                  "trailing-data")
            if not chunk:
                break
            try:
                out = self._inflater.decompress(chunk, min(cap + 1 - len(self._buffer), _PIECE))
            except zlib.error as exc:
                raise FormatError(f"gzip wrapper is corrupt ({exc})", "bad-gzip") from None
            self._buffer += out
            chunk = self._inflater.unconsumed_tail
        if self._inflater.eof and self._inflater.unused_data:
            raise FormatError("bytes follow the gzip member", "trailing-data")

    def _read_header_if_ready(self) -> None:
        """Parse the header block once it is whole; refuse a bad fixed header even before."""
        if self.header is not None:
            return
        need = header_bytes_needed(self._buffer)
        if need is None:
            if not MAGIC.startswith(bytes(self._buffer[:len(MAGIC)])):
                raise FormatError("not an spcodec file (bad magic)", "bad-magic")
            return
        if len(self._buffer) < need:
            _check_fixed_header(self._buffer, self.limits)
            return
        self.header = read_header(self._buffer, self.limits)
        self._decoder = _LayerDecoder(self.header, self.limits)

    def _drain(self) -> list[DecodedLayer]:
        self._read_header_if_ready()
        if self.header is None:
            return []
        if len(self._buffer) > self.header.file_size:
            raise FormatError("bytes follow the last section", "trailing-data")
        done = []
        last = len(self.header.layers) - 1 if self.max_layer is None else \
            min(self.max_layer, len(self.header.layers) - 1)
        view = memoryview(self._buffer)
        try:
            while self._next_layer <= last and \
                    len(self._buffer) >= self.header.layers[self._next_layer].end_offset:
                done.append(self._decoder.decode(view, self._next_layer))
                self._next_layer += 1
        finally:
            view.release()
        return done

    @property
    def complete(self) -> bool:
        """True when every requested layer has been returned."""
        if self.header is None:
            return False
        wanted = len(self.header.layers) if self.max_layer is None else \
            min(self.max_layer + 1, len(self.header.layers))
        return self._next_layer >= wanted

    def close(self) -> None:
        """Declare the end of the data; raise if it stopped inside the header or a layer."""
        if self.header is None:
            raise TruncatedError("the data ends before the header block is complete")
        if self.complete:
            return
        # Like decode(): without max_layer a prefix ending at a layer boundary is valid ([R-11]);
        # with max_layer, every requested layer must have arrived ([R-12]).
        boundary = {layer.end_offset for layer in self.header.layers}
        if self.max_layer is not None or len(self._buffer) not in boundary:
            raise TruncatedError(f"the data ends at byte {len(self._buffer)}, inside layer "
                                 f"{self._next_layer}",
                                 complete_layers=_complete_layers(self.header, len(self._buffer)))


def _check_fixed_header(buffer: bytearray, limits: Limits) -> None:
    """Validate the fixed header early, so a hostile header_size is refused before we wait for it."""
    try:
        read_header(bytes(buffer[:FIXED_HEADER_SIZE]), limits)
    except TruncatedError:
        pass
