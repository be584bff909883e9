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

Coordinates are written as they are in the scene (no axis change and no node transform): the file
holds exactly the decoded Gaussians, and a viewer places them as it places the PLY. The colour space
is ``srgb_rec709_display``, the space 3DGS models are trained in.

Only numpy and the standard library: the format layer stays free of the encoder's dependencies.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np

from .cloud import GaussianCloud
from .errors import UsageError
from .fileio import atomic_write

EXTENSION = "KHR_gaussian_splatting"

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
        sh_attribute(0, 0): cloud.sh_dc,
    }
    for degree in range(1, cloud.sh_degree + 1):
        for n in range(2 * degree + 1):
            attributes[sh_attribute(degree, n)] = cloud.sh_rest[:, degree * degree - 1 + n]
    return {name: np.ascontiguousarray(a, dtype="<f4") for name, a in attributes.items()}


def glb_bytes(cloud: GaussianCloud, generator: str | None = None) -> bytes:
    """The whole ``.glb`` file for ``cloud``: a JSON chunk and one binary chunk."""
    from . import __version__

    attributes = splat_attributes(cloud)
    accessors, views, blobs, offset = [], [], [], 0
    for index, (name, array) in enumerate(attributes.items()):
        components = array.shape[1]
        accessor = {"bufferView": index, "componentType": _FLOAT, "count": len(array),
                    "type": "SCALAR" if components == 1 else f"VEC{components}"}
        if name == "POSITION":  # glTF requires bounds on POSITION
            accessor["min"] = [float(v) for v in array.min(axis=0)]
            accessor["max"] = [float(v) for v in array.max(axis=0)]
        accessors.append(accessor)
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": array.nbytes,
                      "target": _ARRAY_BUFFER})
        blobs.append(array.tobytes())
        offset += array.nbytes  # float32 arrays keep every view 4-byte aligned
    document = {
        "asset": {"version": "2.0", "generator": generator or f"spcodec {__version__}"},
        "extensionsUsed": [EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{
            "attributes": {name: i for i, name in enumerate(attributes)},
            "mode": _POINTS,
            "extensions": {EXTENSION: {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}},
        }]}],
        "buffers": [{"byteLength": offset}],
        "bufferViews": views,
        "accessors": accessors,
    }
    return _pack_glb(json.dumps(document, separators=(",", ":")).encode(), b"".join(blobs))


def write_glb(path: str | os.PathLike, cloud: GaussianCloud) -> None:
    """Write ``cloud`` to ``path`` as a ``.glb`` with ``KHR_gaussian_splatting``, atomically."""
    atomic_write(path, glb_bytes(cloud))


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
