"""The preview of a 1.1 file (spec 7.4): a small whole file in an optional section of layer 0.

A file trained for a tenth of the bytes looks far better than the first tenth of a file trained for
all of them (docs/LOG.md 15.7), so a writer may embed one for a viewer to show until the
file's own layers overtake it. Decoding the scene never looks inside it ([R-102]): this module is
the one place that does, and what it finds wrong concerns the preview only ([R-103]).
"""

from __future__ import annotations

from dataclasses import dataclass

from spcodec.cloud import GaussianCloud
from spcodec.codecs import is_gzip
from spcodec.container import PREVIEW_PREFIX_SIZE, PreviewPayload, SectionType
from spcodec.errors import FormatError, TruncatedError
from spcodec.limits import DEFAULT_LIMITS, Limits

from .api import Source, _unwrap, decode_layers, read_source
from .header import Header, Section, read_header
from .layers import section_payload


@dataclass
class DecodedPreview:
    """A file's preview: its Gaussians, and the layer of the file that replaces it."""

    cloud: GaussianCloud
    takeover_layer: int
    """Show the preview until layers ``0..takeover_layer`` of the file have arrived ([R-104])."""
    header: Header
    """The embedded file's header."""
    section: Section
    """Where the preview lies in the (inner) file: a viewer needs bytes up to ``section.end``."""


def find_preview(header: Header) -> Section | None:
    """The ``PREVIEW`` section of layer 0, or None ([R-103]; those of other layers are not
    previews). Two in layer 0 are ``duplicate-section``."""
    found = [sec for sec in header.layers[0].sections if sec.type == SectionType.PREVIEW]
    if len(found) > 1:
        raise FormatError("layer 0 holds PREVIEW twice", "duplicate-section")
    return found[0] if found else None


def decode_preview(source: Source, limits: Limits | None = None) -> DecodedPreview | None:
    """Decode the preview of a file, or of a prefix that holds the preview's section; None when
    the file has none. Needs the header block and the section's bytes, nothing of the layers."""
    limits = limits or DEFAULT_LIMITS
    data, _ = _unwrap(read_source(source, limits), limits)
    header = read_header(data, limits)
    section = find_preview(header)
    if section is None:
        return None
    if len(data) < section.end:
        raise TruncatedError(f"the data ends at byte {len(data)}, inside the PREVIEW section "
                             f"(bytes {section.offset}..{section.end})")
    return parse_preview(section_payload(data, section), header, section, limits)


def parse_preview(raw: bytes, header: Header, section: Section, limits: Limits) -> DecodedPreview:
    """The checks of [R-103] on an inflated ``PREVIEW`` payload, then the embedded file's decode
    (section 11 applied to it as to any whole file)."""
    if len(raw) < PREVIEW_PREFIX_SIZE:
        raise FormatError(f"the PREVIEW payload has {len(raw)} bytes, fewer than its "
                          f"{PREVIEW_PREFIX_SIZE}-byte prefix", "bad-section")
    fields = PreviewPayload.parse(raw)
    if fields.reserved:
        raise FormatError("the PREVIEW payload's reserved field is not zero", "reserved-nonzero")
    if fields.takeover_layer >= len(header.layers):
        raise FormatError(f"the preview's takeover layer {fields.takeover_layer} is not a layer "
                          f"of the file (it has {len(header.layers)})", "bad-value")
    inner = memoryview(raw)[PREVIEW_PREFIX_SIZE:]
    if is_gzip(inner):
        raise FormatError("the preview's embedded file is gzip-wrapped", "bad-section")
    embedded = read_header(inner, limits)
    if len(inner) != embedded.file_size:
        raise FormatError(f"the preview's embedded file holds {len(inner)} bytes, its header "
                          f"says {embedded.file_size}", "bad-section")
    if any(sec.type == SectionType.PREVIEW for sec in embedded.sections):
        raise FormatError("the preview's embedded file has a preview of its own", "bad-section")
    result = decode_layers(inner, limits=limits)
    return DecodedPreview(result.cloud, fields.takeover_layer, result.header, section)
