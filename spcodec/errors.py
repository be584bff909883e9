"""Errors raised by spcodec.

Every problem with an input file is a :class:`FormatError` (or a subclass), so an application that
embeds the decoder catches exactly one type. Each error carries a stable ``code`` string; the codes are
listed in the specification (``spec/bitstream-v1.md``, section "Error conditions") and the conformance
vectors name the code they expect, so a rejection is checked for the right reason and not just for
"some failure".

:class:`UsageError` is for bad arguments and bad requests from a caller (an unwritable output path,
an impossible option), which are not defects of a file.
"""

from __future__ import annotations


class SpcodecError(Exception):
    """Root of every error spcodec raises on purpose."""


class UsageError(SpcodecError, ValueError):
    """A caller asked for something that cannot be done (bad option, unwritable path...)."""


class Interrupted(SpcodecError):
    """A long job (a retraining encode) stopped on request after saving what it needs to
    continue; the message says how to resume."""


class FormatError(SpcodecError, ValueError):
    """An input file (bitstream or PLY) is malformed, unsupported or exceeds a limit.

    ``code`` is one of the stable codes of the specification's error list.
    """

    default_code = "bad-section"

    def __init__(self, message: str, code: str | None = None) -> None:
        super().__init__(message)
        self.code = code or self.default_code

    def __str__(self) -> str:
        return f"{self.args[0]} [{self.code}]"


class TruncatedError(FormatError):
    """The data ends before a structure it declares is complete."""

    default_code = "truncated"

    def __init__(self, message: str, code: str | None = None,
                 complete_layers: int | None = None) -> None:
        super().__init__(message, code)
        #: How many leading layers the data holds whole (None: not known). When positive, they
        #: decode with ``max_layer=complete_layers - 1``, which a tool can suggest.
        self.complete_layers = complete_layers


class ChecksumError(FormatError):
    """A CRC-32 does not match the bytes it covers."""

    default_code = "section-crc"


class LimitError(FormatError):
    """A declared size or count exceeds the decoder's :class:`~spcodec.limits.Limits`."""

    default_code = "limit-exceeded"


class UnsupportedError(FormatError):
    """The file is well formed but uses a version or feature this decoder does not implement."""

    default_code = "unsupported-version"


#: Every error code the specification defines, with a one-line meaning. Kept here so tests can check
#: that the spec, the code and the conformance vectors use the same names.
ERROR_CODES: dict[str, str] = {
    "bad-magic": "the data does not start with the spcodec magic or a gzip header",
    "unsupported-version": "the major version is not 1",
    "reserved-nonzero": "a reserved field or flag bit is not zero",
    "truncated": "the data ends inside the header or inside a layer",
    "trailing-data": "bytes follow the end of the last section",
    "header-crc": "the header CRC-32 does not match",
    "section-crc": "a section's CRC-32 does not match its stored bytes",
    "limit-exceeded": "a declared count or size exceeds the decoder's limits",
    "bad-layout": "the layer table or table of contents is inconsistent",
    "unknown-codec": "a section uses a codec id this decoder does not know",
    "codec-unavailable": "a section uses a known codec whose library is not installed",
    "unknown-required-section": "a required section has a type this decoder does not know",
    "missing-section": "a layer lacks a section it must contain",
    "duplicate-section": "a layer contains a section type more than once",
    "decompression-failed": "a compressed section is corrupt",
    "length-mismatch": "a section inflates to a length other than its declared raw length",
    "bad-section": "a section's payload is inconsistent with its declared structure",
    "bad-value": "a value is out of its allowed range or not finite",
    "draco-failed": "a Draco position blob cannot be decoded or has the wrong point count",
    "bad-gzip": "the gzip wrapper is corrupt",
    "bad-metadata": "the metadata section is not a UTF-8 JSON object",
    "ply-invalid": "a PLY file is malformed or lacks a required property",
    "dataset-invalid": "a dataset folder lacks files, has unparsable poses or an unsupported camera",
}
