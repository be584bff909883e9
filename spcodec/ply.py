"""PLY input and output for 3DGS scenes.

Reading finds properties *by name* and accepts:

* the INRIA 3DGS layout (``x y z [nx ny nz] f_dc_0..2 [f_rest_*] opacity scale_0..2 rot_0..3``),
  with or without normals and with 0, 9, 24 or 45 ``f_rest`` properties (SH degree 0..3), in float or
  double, in any property order;
* PlayCanvas/SuperSplat ``compressed.ply`` (``chunk`` + packed ``vertex`` elements, optional ``sh``
  element), which is unpacked to the same parametrization, so a peer codec's output can be evaluated.

Writing always produces the INRIA layout that viewers open (binary little-endian float32, zero normals,
``f_rest`` channel-major), atomically.
"""

from __future__ import annotations

import os
from typing import BinaryIO

import numpy as np

from .cloud import SH_C0, SH_REST_COUNTS, GaussianCloud, sh_degree_for_rest_count
from .errors import FormatError
from .fileio import atomic_write

_REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
_PACKED = ["packed_position", "packed_rotation", "packed_scale", "packed_color"]
_CHUNK_PROPS = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
                "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y",
                "max_scale_z"]
_CHUNK_COLOR_PROPS = ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"]
_SPLATS_PER_CHUNK = 256


def _refuse_other_formats(path: str | os.PathLike | BinaryIO, name) -> None:
    """Name the format of a file that is no PLY, from its first bytes, instead of letting the PLY
    parser choke on binary data."""
    from .container import GZIP_MAGIC, MAGIC

    if hasattr(path, "read"):
        return  # a stream: nothing to peek at without consuming it
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
        if head.startswith(GZIP_MAGIC):  # a gzip-wrapped .spc, or an SPZ of versions 1-3
            import gzip
            with gzip.open(path, "rb") as fh:
                head = fh.read(8)
    except (OSError, EOFError):
        return  # the parser reports a missing or unreadable file itself
    if head.startswith(MAGIC):
        raise FormatError(f"{name}: this is an .spc file, not a PLY; decode it first with "
                          "'spcodec decode' (or give the original PLY)", "ply-invalid")
    kinds = {b"NGSP": "an SPZ file", b"glTF": "a binary glTF (.glb)", b"PK\x03\x04":
             "a zip archive (SOG?)"}
    for magic, kind in kinds.items():
        if head.startswith(magic):
            raise FormatError(f"{name}: this is {kind}, not a PLY; convert it to a 3DGS PLY "
                              "first", "ply-invalid")


def read_ply(path: str | os.PathLike | BinaryIO) -> GaussianCloud:
    """Read a 3DGS PLY (INRIA layout or PlayCanvas compressed) into a :class:`GaussianCloud`."""
    from plyfile import PlyData, PlyParseError  # plyfile is a core dependency, imported lazily

    name = getattr(path, "name", path)
    _refuse_other_formats(path, name)
    try:
        ply = PlyData.read(path)
    except (PlyParseError, ValueError, EOFError, IndexError, KeyError, TypeError) as exc:
        raise FormatError(f"{name}: not a readable PLY file ({_first_line(exc)})",
                          "ply-invalid") from None
    elements = {el.name: el for el in ply.elements}
    if "vertex" not in elements:
        raise FormatError(f"{name}: PLY has no 'vertex' element", "ply-invalid")
    vertex = elements["vertex"].data
    names = set(vertex.dtype.names or ())
    if "chunk" in elements and set(_PACKED) <= names:
        return _read_compressed(elements, name)
    return cloud_from_vertex(vertex, inria_rest_names(names, name))


def inria_rest_names(names: set[str], name) -> list[str]:
    """The ``f_rest_*`` properties of a vertex element with ``names``, in order, once it has
    every 3DGS property and a whole SH degree of them (a FormatError naming ``name``
    otherwise). Shared by :func:`read_ply` and chunked readers of the same layout."""
    missing = [p for p in _REQUIRED if p not in names]
    if missing:
        raise FormatError(f"{name}: PLY lacks the 3DGS properties {', '.join(missing)}",
                          "ply-invalid")
    rest_names = sorted((p for p in names if p.startswith("f_rest_")),
                        key=lambda p: int(p[7:]) if p[7:].isdigit() else -1)
    if any(not p[7:].isdigit() for p in rest_names) or \
            [int(p[7:]) for p in rest_names] != list(range(len(rest_names))):
        raise FormatError(f"{name}: f_rest properties are not numbered 0..N-1", "ply-invalid")
    if len(rest_names) % 3 or len(rest_names) // 3 not in SH_REST_COUNTS.values():
        raise FormatError(f"{name}: {len(rest_names)} f_rest properties match no SH degree 0..3",
                          "ply-invalid")
    return rest_names


def cloud_from_vertex(vertex: np.ndarray, rest_names: list[str]) -> GaussianCloud:
    """The Gaussians of INRIA vertex records (a structured array or memory map; ``rest_names``
    from :func:`inria_rest_names`)."""

    def cols(*props: str) -> np.ndarray:
        return np.stack([np.asarray(vertex[p], dtype=np.float32) for p in props], axis=1)

    k = len(rest_names) // 3
    rest = cols(*rest_names) if rest_names else np.zeros((len(vertex), 0), np.float32)
    # INRIA stores f_rest channel-major (all R coefficients, then G, then B).
    sh_rest = rest.reshape(len(vertex), 3, k).transpose(0, 2, 1)
    return GaussianCloud(
        means=cols("x", "y", "z"),
        scales=cols("scale_0", "scale_1", "scale_2"),
        quats=cols("rot_0", "rot_1", "rot_2", "rot_3"),
        opacities=cols("opacity")[:, 0],
        sh_dc=cols("f_dc_0", "f_dc_1", "f_dc_2"),
        sh_rest=sh_rest,
    )


def ply_dtype(sh_degree: int) -> np.dtype:
    """The INRIA vertex record for a scene of the given SH degree (float32 little-endian)."""
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * SH_REST_COUNTS[sh_degree])]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return np.dtype([(n, "<f4") for n in names])


def ply_bytes(cloud: GaussianCloud) -> tuple[bytes, np.ndarray]:
    """Header and vertex records of the INRIA PLY for ``cloud``."""
    dtype = ply_dtype(cloud.sh_degree)
    records = np.zeros(len(cloud), dtype=dtype)
    for i, axis in enumerate("xyz"):
        records[axis] = cloud.means[:, i]
    for i in range(3):
        records[f"f_dc_{i}"] = cloud.sh_dc[:, i]
        records[f"scale_{i}"] = cloud.scales[:, i]
    k = cloud.sh_rest.shape[1]
    channel_major = cloud.sh_rest.transpose(0, 2, 1).reshape(len(cloud), 3 * k)
    for i in range(3 * k):
        records[f"f_rest_{i}"] = channel_major[:, i]
    records["opacity"] = cloud.opacities
    for i in range(4):
        records[f"rot_{i}"] = cloud.quats[:, i]
    header = ["ply", "format binary_little_endian 1.0", "comment written by spcodec",
              f"element vertex {len(cloud)}"]
    header += [f"property float {n}" for n in dtype.names]
    header.append("end_header")
    return ("\n".join(header) + "\n").encode("ascii"), records


def write_ply(path: str | os.PathLike, cloud: GaussianCloud) -> None:
    """Write ``cloud`` as an INRIA-layout binary PLY, atomically."""
    header, records = ply_bytes(cloud)

    def produce(out: BinaryIO) -> None:
        out.write(header)
        # write() of the array's own memory: no copy, and unlike numpy's tofile() it works on
        # pipes and in-memory streams (tofile() on a pipe can write nothing and say nothing)
        out.write(memoryview(np.ascontiguousarray(records)).cast("B"))

    atomic_write(path, produce)


# --------------------------------------------------------------- PlayCanvas compressed.ply
def _read_compressed(elements: dict, name) -> GaussianCloud:
    """Unpack SuperSplat's compressed PLY: per-chunk ranges plus 32-bit packed vertex fields."""
    chunk = elements["chunk"].data
    vertex = elements["vertex"].data
    missing = [p for p in _CHUNK_PROPS if p not in (chunk.dtype.names or ())]
    if missing:
        raise FormatError(f"{name}: compressed PLY chunk lacks {', '.join(missing)}",
                          "ply-invalid")
    n = len(vertex)
    if len(chunk) * _SPLATS_PER_CHUNK < n:
        raise FormatError(f"{name}: {len(chunk)} chunks cannot hold {n} splats", "ply-invalid")
    ci = np.arange(n) // _SPLATS_PER_CHUNK

    def ranges(prefix_lo: str, prefix_hi: str, axes: str) -> tuple[np.ndarray, np.ndarray]:
        lo = np.stack([np.asarray(chunk[f"{prefix_lo}{a}"], np.float64)[ci] for a in axes], 1)
        hi = np.stack([np.asarray(chunk[f"{prefix_hi}{a}"], np.float64)[ci] for a in axes], 1)
        return lo, hi

    def lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
        return lo * (1.0 - t) + hi * t

    pos = _unpack_11_10_11(np.asarray(vertex["packed_position"], np.uint32))
    scl = _unpack_11_10_11(np.asarray(vertex["packed_scale"], np.uint32))
    col = _unpack_8888(np.asarray(vertex["packed_color"], np.uint32))
    means = lerp(*ranges("min_", "max_", "xyz"), pos)
    scales = lerp(*ranges("min_scale_", "max_scale_", "xyz"), scl)
    if all(p in chunk.dtype.names for p in _CHUNK_COLOR_PROPS):
        rgb = lerp(*ranges("min_", "max_", "rgb"), col[:, :3])
    else:
        rgb = col[:, :3]
    opacity = np.clip(col[:, 3], 1e-6, 1 - 1e-6)
    sh_rest = np.zeros((n, 0, 3), np.float32)
    if "sh" in elements:
        sh = elements["sh"].data
        rest_names = [p for p in sh.dtype.names if p.startswith("f_rest_")]
        k = len(rest_names) // 3
        if len(rest_names) % 3 or k not in SH_REST_COUNTS.values() or len(sh) != n:
            raise FormatError(f"{name}: compressed PLY 'sh' element does not match an SH degree",
                              "ply-invalid")
        rest_names.sort(key=lambda p: int(p[7:]))
        raw = np.stack([np.asarray(sh[p], np.float64) for p in rest_names], 1)
        sh_rest = ((raw / 256.0 - 0.5) * 8.0).reshape(n, 3, k).transpose(0, 2, 1)
    sh_degree_for_rest_count(sh_rest.shape[1])
    return GaussianCloud(
        means=means, scales=scales, quats=_unpack_rotation(np.asarray(vertex["packed_rotation"],
                                                                        np.uint32)),
        opacities=np.log(opacity / (1.0 - opacity)), sh_dc=(rgb - 0.5) / SH_C0, sh_rest=sh_rest,
    )


def _unorm(value: np.ndarray, bits: int) -> np.ndarray:
    mask = (1 << bits) - 1
    return (value & mask).astype(np.float64) / mask


def _unpack_11_10_11(v: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(v >> 21, 11), _unorm(v >> 11, 10), _unorm(v, 11)], axis=1)


def _unpack_8888(v: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(v >> 24, 8), _unorm(v >> 16, 8), _unorm(v >> 8, 8), _unorm(v, 8)], 1)


def _unpack_rotation(v: np.ndarray) -> np.ndarray:
    """Smallest-three quaternion: 2 bits for the largest component's index, 3 x 10 bits."""
    scale = np.sqrt(2.0)  # the three small components lie in [-1/sqrt2, 1/sqrt2]
    small = np.stack([(_unorm(v >> s, 10) - 0.5) * scale for s in (20, 10, 0)], axis=1)
    largest = np.sqrt(np.maximum(0.0, 1.0 - (small ** 2).sum(axis=1)))
    which = (v >> 30).astype(np.int64)
    out = np.empty((len(v), 4))
    for slot in range(4):
        rows = which == slot
        others = [c for c in range(4) if c != slot]
        out[rows, slot] = largest[rows]
        out[np.ix_(rows, others)] = small[rows]
    return out


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__
