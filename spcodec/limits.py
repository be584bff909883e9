"""Resource limits a decoder enforces on untrusted input (spec section 9, [R-60]..[R-62]).

Every count or length that a file declares is checked against these limits *before* anything sized
from it is allocated, so a hostile file of a few bytes cannot make the decoder reserve gigabytes.
The defaults admit any realistic scene (tens of millions of Gaussians) and can be raised by a caller
that trusts its input.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import LimitError

KIB = 1 << 10
MIB = 1 << 20
GIB = 1 << 30


@dataclass(frozen=True)
class Limits:
    """Upper bounds applied while decoding; see the spec's "Limits" section."""

    #: Largest inner (un-gzipped) file accepted, in bytes.
    max_file_bytes: int = 4 * GIB
    #: Largest total number of Gaussians over all layers.
    max_gaussians: int = 64_000_000
    #: Largest number of layers in the layer table.
    max_layers: int = 1024
    #: Largest number of entries in the table of contents.
    max_sections: int = 4096
    #: Largest number of sketch clusters.
    max_clusters: int = 4_000_000
    #: Largest raw (decompressed) length of one section, in bytes.
    max_section_bytes: int = 2 * GIB
    #: Largest metadata section, in bytes.
    max_metadata_bytes: int = 16 * MIB
    #: The raw lengths of all sections together may exceed ``max_expansion_ratio`` times the
    #: file's size only while they stay under ``expansion_floor_bytes``: a tiny file cannot
    #: declare gigabytes of content.
    max_expansion_ratio: float = 1024.0
    expansion_floor_bytes: int = 64 * MIB
    #: A file may declare more than ``gaussian_floor`` Gaussians only at up to this many per byte
    #: of file: real files spend at least ~1 byte per Gaussian, and Draco can code thousands of
    #: points per byte, so without this a 125 KB file could demand gigabytes of output.
    max_gaussians_per_byte: float = 64.0
    gaussian_floor: int = 1_000_000

    def check(self, what: str, value: int, limit: int) -> None:
        """Raise :class:`LimitError` naming ``what`` when ``value`` exceeds ``limit``."""
        if value > limit:
            raise LimitError(f"{what} is {value}, above the limit of {limit}")

    def check_gaussian_density(self, gaussians: int, file_bytes: int) -> None:
        """Refuse a file that declares far more Gaussians than its size can carry ([R-61])."""
        allowed = max(self.gaussian_floor, int(self.max_gaussians_per_byte * file_bytes))
        if gaussians > allowed:
            raise LimitError(f"a {file_bytes}-byte file declares {gaussians} Gaussians (more "
                             f"than {self.max_gaussians_per_byte:g} per byte)")

    def check_expansion(self, raw_total: int, file_bytes: int) -> None:
        """Refuse a file whose sections would inflate far beyond its own size."""
        allowed = max(self.expansion_floor_bytes, int(self.max_expansion_ratio * file_bytes))
        if raw_total > allowed:
            raise LimitError(
                f"sections declare {raw_total} raw bytes for a {file_bytes}-byte file "
                f"(more than {self.max_expansion_ratio:g}x expansion)"
            )


DEFAULT_LIMITS = Limits()
