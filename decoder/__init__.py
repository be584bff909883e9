"""The minimal-dependency spcodec decoder (numpy, construct, DracoPy; zstandard optional).

Importing this package never imports torch, scikit-learn or scipy ([R-95]); a test enforces it.
"""

from .api import DecodedLayer, DecodeResult, StreamDecoder, decode, decode_layers
from .header import Header, Layer, Section, read_header
from .info import FileInfo, inspect, parse_metadata
from .preview import DecodedPreview, decode_preview, find_preview

__all__ = [
    "DecodedLayer", "DecodedPreview", "DecodeResult", "FileInfo", "Header", "Layer", "Section",
    "StreamDecoder", "decode", "decode_layers", "decode_preview", "find_preview", "inspect",
    "parse_metadata", "read_header",
]
