"""glTF output: a :class:`GaussianCloud` as a binary glTF (``.glb``) with ``KHR_gaussian_splatting``.

The Khronos extension stores splats as one ``POINTS`` primitive whose attributes are

* ``POSITION`` (VEC3 float): the centres, unchanged;
* ``KHR_gaussian_splatting:ROTATION`` (VEC4 float): unit quaternions in glTF order (x, y, z, w),
  where our clouds (and the INRIA PLY) hold (w, x, y, z);
* ``KHR_gaussian_splatting:SCALE`` (VEC3 float): *linear* standard deviations, ``exp`` of our
  log-scales;
* ``KHR_gaussian_splatting:OPACITY`` (SCALAR float): opacity *after* the sigmoid, in [0, 1];
* ``KHR_gaussian_splatting:SH_DEGREE_l_COEF_n`` (VEC3 float, RGB): SH coefficient ``n`` of degree
  ``l``, ordered from order m = -l to m = +l. That is the INRIA order of ``f_rest`` coefficients
  within a degree, so coefficient ``n`` of degree ``l >= 1`` is ``sh_rest[:, l*l - 1 + n]``, and
  degree 0 is ``sh_dc``.

plus ``COLOR_0`` (VEC4 float: the view-independent colour ``0.5 + C0 * dc`` clamped to [0, 1]
and the opacity), which viewers without the extension draw as coloured points.

glTF is +Y up; a scene is stored in its own coordinates with its up axis in the file's metadata
(``-y`` for COLMAP-derived scenes, the default when a file does not say). The Gaussians are written
as they are, exactly the decoded values, and the node's rotation turns the scene's up into +Y, so
a viewer shows it upright without any data being resampled (SH coefficients would need rotating).
The colour space is ``srgb_rec709_display``, the space 3DGS models are trained in.

:func:`compressed_glb_bytes` writes the other kind: the primitive declares the same attributes
(accessors with counts but no data) and :data:`COMPRESSION` in the ``KHR_gaussian_splatting``
object names a buffer view holding the ``.spc`` file itself, as
``KHR_gaussian_splatting_compression_spz_2`` does for SPZ: a loader that knows the extension
decodes the view; the layers of the ``.spc`` stream as in a plain ``.spc``.

Only numpy and the standard library: the format layer stays free of the encoder's dependencies.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np

from .cloud import SH_C0, GaussianCloud
from .errors import FormatError, UsageError
from .fileio import atomic_write

_UP_TO_Y = {  # glTF (x, y, z, w) quaternions turning each signed axis into +Y
    "+y": (0.0, 0.0, 0.0, 1.0),
    "-y": (1.0, 0.0, 0.0, 0.0),  # half a turn about x: y -> -y, z -> -z
    "+z": (-0.5 ** 0.5, 0.0, 0.0, 0.5 ** 0.5),  # a quarter turn about x: z -> y
    "-z": (0.5 ** 0.5, 0.0, 0.0, 0.5 ** 0.5),
    "+x": (0.0, 0.0, 0.5 ** 0.5, 0.5 ** 0.5),  # a quarter turn about z: x -> y
    "-x": (0.0, 0.0, -0.5 ** 0.5, 0.5 ** 0.5),
}


def up_rotation(up: str | None) -> tuple[float, float, float, float]:
    """The node rotation (glTF x, y, z, w) that turns a scene's ``up`` axis into glTF's +Y;
    ``None`` (a file that does not say) means ``-y``, the encoder's default."""
    key = "-y" if up is None else ("+" + up if up[:1] not in "+-" else up).lower()
    if key not in _UP_TO_Y:
        raise UsageError(f"unknown up axis {up!r}: one of +x -x +y -y +z -z")
    return _UP_TO_Y[key]

EXTENSION = "KHR_gaussian_splatting"
COMPRESSION = "SPCODEC_gaussian_splatting_compression_spc"
"""Our vendor extension inside ``KHR_gaussian_splatting``: ``{"bufferView": N}``, the ``.spc``."""

GLB_MAGIC = b"glTF"
GLB_VERSION = 2
_CHUNK_JSON = 0x4E4F534A  # "JSON"
_CHUNK_BIN = 0x004E4942  # "BIN\0"
_FLOAT = 5126  # glTF componentType for float32
_ARRAY_BUFFER = 34962  # glTF bufferView target for vertex attributes
_POINTS = 0


def sh_attribute(degree: int, coefficient: int) -> str:
    """The attribute name of SH coefficient ``coefficient`` (0..2*degree) of ``degree``."""
    return f"{EXTENSION}:SH_DEGREE_{degree}_COEF_{coefficient}"


def splat_attributes(cloud: GaussianCloud) -> dict[str, np.ndarray]:
    """The primitive's attributes, name -> float32 array (N, components), in the extension's
    conventions (see the module docstring)."""
    if len(cloud) == 0:
        raise UsageError("a glTF file cannot hold an empty scene (accessors need at least one "
                         "element)")
    quats = cloud.quats.astype(np.float64)
    norms = np.linalg.norm(quats, axis=1)
    unit = np.where(norms[:, None] > 1e-8, quats / np.maximum(norms, 1e-300)[:, None],
                    np.array([1.0, 0.0, 0.0, 0.0]))
    with np.errstate(over="ignore"):
        scales = np.exp(cloud.scales.astype(np.float64)).astype(np.float32)
    if not np.isfinite(scales).all():
        raise UsageError("a log-scale is too large for a float32 linear scale in glTF "
                         f"(largest {float(cloud.scales.max()):.1f})")
    attributes = {
        "POSITION": cloud.means,
        f"{EXTENSION}:ROTATION": unit[:, [1, 2, 3, 0]],
        f"{EXTENSION}:SCALE": scales,
        f"{EXTENSION}:OPACITY": cloud.activated_opacity()[:, None],
        "COLOR_0": np.concatenate([np.clip(0.5 + SH_C0 * cloud.sh_dc.astype(np.float64), 0, 1),
                                   cloud.activated_opacity()[:, None]], axis=1),
        sh_attribute(0, 0): cloud.sh_dc,
    }
    for degree in range(1, cloud.sh_degree + 1):
        for n in range(2 * degree + 1):
            attributes[sh_attribute(degree, n)] = cloud.sh_rest[:, degree * degree - 1 + n]
    return {name: np.ascontiguousarray(a, dtype="<f4") for name, a in attributes.items()}


def _accessor(name: str, array: np.ndarray) -> dict:
    """An accessor of ``array`` (no data source yet); POSITION carries the bounds glTF needs."""
    components = array.shape[1]
    accessor = {"componentType": _FLOAT, "count": len(array),
                "type": "SCALAR" if components == 1 else f"VEC{components}"}
    if name == "POSITION":
        accessor["min"] = [float(v) for v in array.min(axis=0)]
        accessor["max"] = [float(v) for v in array.max(axis=0)]
    return accessor


def _document(attributes: dict[str, np.ndarray], up: str | None, splat: dict,
              generator: str | None, required: list[str] = ()) -> dict:
    from . import __version__

    node: dict = {"mesh": 0}
    rotation = up_rotation(up)
    if rotation != (0.0, 0.0, 0.0, 1.0):
        node["rotation"] = list(rotation)
    document = {
        "asset": {"version": "2.0", "generator": generator or f"spcodec {__version__}"},
        "extensionsUsed": [EXTENSION, *required],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [node],
        "meshes": [{"primitives": [{
            "attributes": {name: i for i, name in enumerate(attributes)},
            "mode": _POINTS,
            "extensions": {EXTENSION: {"kernel": "ellipse", "colorSpace": "srgb_rec709_display",
                                       **splat}},
        }]}],
        "accessors": [_accessor(name, array) for name, array in attributes.items()],
    }
    if required:
        document["extensionsRequired"] = list(required)
    return document


def glb_bytes(cloud: GaussianCloud, up: str | None = None, generator: str | None = None) -> bytes:
    """The whole ``.glb`` file for ``cloud`` (whose up axis is ``up``): a JSON chunk and one
    binary chunk with every attribute."""
    attributes = splat_attributes(cloud)
    document = _document(attributes, up, {}, generator)
    views, blobs, offset = [], [], 0
    for index, array in enumerate(attributes.values()):
        document["accessors"][index]["bufferView"] = index
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": array.nbytes,
                      "target": _ARRAY_BUFFER})
        blobs.append(array.tobytes())
        offset += array.nbytes  # float32 arrays keep every view 4-byte aligned
    document["buffers"] = [{"byteLength": offset}]
    document["bufferViews"] = views
    return _pack_glb(json.dumps(document, separators=(",", ":")).encode(), b"".join(blobs))


def compressed_glb_bytes(spc: bytes, generator: str | None = None) -> bytes:
    """A ``.glb`` whose splats are the ``.spc`` file ``spc`` itself (see the module docstring):
    the accessors say what it decodes to (counts, types, the POSITION bounds glTF requires), the
    one buffer view holds its bytes, and the node turns its up axis into +Y."""
    from .decoder import decode_layers, inspect

    cloud = decode_layers(spc).cloud
    up = (inspect(spc).metadata or {}).get("up")
    document = _document(splat_attributes(cloud), up, {"extensions": {COMPRESSION: {
        "bufferView": 0}}}, generator, required=[COMPRESSION])
    document["buffers"] = [{"byteLength": len(spc)}]
    document["bufferViews"] = [{"buffer": 0, "byteOffset": 0, "byteLength": len(spc)}]
    return _pack_glb(json.dumps(document, separators=(",", ":")).encode(), spc)


def write_glb(path: str | os.PathLike, cloud: GaussianCloud, up: str | None = None) -> None:
    """Write ``cloud`` to ``path`` as a ``.glb`` with ``KHR_gaussian_splatting``, atomically."""
    atomic_write(path, glb_bytes(cloud, up))


def _pack_glb(json_bytes: bytes, binary: bytes) -> bytes:
    """GLB container: 12-byte header, JSON chunk padded with spaces, BIN chunk padded with zeros."""
    json_chunk = json_bytes + b" " * (-len(json_bytes) % 4)
    bin_chunk = binary + b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(json_chunk) + 8 + len(bin_chunk)
    if total >= 1 << 32:
        raise UsageError(f"the scene needs {total} bytes, more than a GLB file can hold (4 GiB)")
    return b"".join([
        GLB_MAGIC, struct.pack("<II", GLB_VERSION, total),
        struct.pack("<II", len(json_chunk), _CHUNK_JSON), json_chunk,
        struct.pack("<II", len(bin_chunk), _CHUNK_BIN), bin_chunk,
    ])


# ------------------------------------------------------------- reading an embedded .spc
def embedded_spc(glb: bytes, name: str) -> bytes:
    """The bytes of the buffer view that a primitive's ``KHR_gaussian_splatting`` names through
    ``SPCODEC_gaussian_splatting_compression_spc`` (:func:`compressed_glb_bytes` writes it)."""
    try:
        document, binary = _glb_chunks(glb)
        view = _spc_view(document)
        spc = None if view is None else _view_bytes(view, binary)
    except (struct.error, ValueError, KeyError, IndexError, TypeError, AttributeError,
            RecursionError) as exc:
        raise FormatError(f"{name}: a glTF file whose embedded .spc cannot be found (malformed "
                          f"glTF: {exc.__class__.__name__})", "bad-magic") from None
    if spc is None:
        raise UsageError(f"{name} is a glTF file whose splats are glTF accessors, not an embedded "
                         f".spc ({COMPRESSION}, as 'spcodec embed' writes): view it with 'spcodec "
                         f"serve {name}' or any viewer with {EXTENSION}, or use the .spc it came "
                         "from")
    return spc


def _glb_chunks(glb: bytes) -> tuple[dict, bytes]:
    """The JSON document and the binary chunk (empty when absent) of a binary glTF."""
    json_length, json_type = struct.unpack_from("<II", glb, 12)
    document = json.loads(glb[20:20 + json_length])
    if json_type != _CHUNK_JSON or not isinstance(document, dict):
        raise ValueError("the first chunk is no JSON object")
    rest = 20 + json_length
    if len(glb) < rest + 8:
        return document, b""
    bin_length, _ = struct.unpack_from("<II", glb, rest)
    return document, glb[rest + 8:rest + 8 + bin_length]


def _view_bytes(view: dict, binary: bytes) -> bytes:
    """A buffer view's bytes in the GLB's binary chunk (buffer 0), checked against its end."""
    start, length = view.get("byteOffset", 0), view["byteLength"]
    valid = view.get("buffer", 0) == 0 and all(type(v) is int and v >= 0 for v in (start, length))
    if not valid or start + length > len(binary):
        raise ValueError("the .spc buffer view lies outside the binary chunk")
    return binary[start:start + length]


def _spc_view(document: dict) -> dict | None:
    """The buffer view holding the .spc; None when no primitive names one."""
    for mesh in document.get("meshes", []):
        for primitive in mesh.get("primitives", []):
            splat = primitive.get("extensions", {}).get(EXTENSION, {})
            link = splat.get("extensions", {}).get(COMPRESSION)
            if link is not None:
                index = link["bufferView"]
                if type(index) is not int or index < 0:
                    raise ValueError(f"bufferView {index!r}")
                return document["bufferViews"][index]
    return None
