"""The minimal-dependency spcodec decoder (numpy, construct, DracoPy; zstandard optional).

Importing this package never imports torch, scikit-learn or scipy ([R-95]); a test enforces it.
"""

from .api import (
    DecodedLayer,
    DecodeResult,
    FileInfo,
    StreamDecoder,
    decode,
    decode_layers,
    inspect,
    parse_metadata,
)
from .header import Header, Layer, Section, read_header

__all__ = [
    "DecodedLayer", "DecodeResult", "FileInfo", "Header", "Layer", "Section", "StreamDecoder",
    "decode", "decode_layers", "inspect", "parse_metadata", "read_header",
]
