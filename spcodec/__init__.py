"""spcodec: the Sketch&Patch++ bitstream format and its reference codec.

The format layer (this package) holds the scene model, PLY I/O, the container definitions, the
section codecs and the writer; :mod:`spcodec.decoder` decodes files; :mod:`spcodec.encoder` (extra
``encoder``) builds them from a 3DGS scene.
"""

from .cloud import GaussianCloud
from .errors import (
    ChecksumError,
    FormatError,
    LimitError,
    SpcodecError,
    TruncatedError,
    UnsupportedError,
    UsageError,
)
from .limits import Limits
from .ply import read_ply, write_ply

__version__ = "0.1.0"

# needs the above:
from .decoder import StreamDecoder, decode, decode_layers, decode_preview, inspect  # noqa: E402

__all__ = [
    "ChecksumError", "FormatError", "GaussianCloud", "LimitError", "Limits", "SpcodecError",
    "StreamDecoder", "TruncatedError", "UnsupportedError", "UsageError", "__version__", "decode",
    "decode_layers", "decode_preview", "inspect", "read_ply", "write_ply",
]
