"""Decoded outputs as the conformance suite sees them: INRIA PLY properties, and their comparison.

Every decoder's output, ours in-process or another implementation's PLY file, becomes one float32
array per PLY property name (spec Annex E, [R-98]), so one comparison serves both. A PLY written by
a decoder under test is read strictly: the contract in ``conformance/README.md`` says exactly which
properties it holds, and a file that strays from it fails rather than being guessed at.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from spcodec.cloud import SH_REST_COUNTS, GaussianCloud
from spcodec.ply import ply_bytes

from .manifest import Expected

Properties = dict[str, np.ndarray]
"""One float32 array per PLY property name, all of the same length."""

NORMALS = ("nx", "ny", "nz")


def property_groups(sh_degree: int) -> dict[str, tuple[str, ...]]:
    """The PLY properties of a decode, by the groups the tolerances are given for."""
    rest = 3 * SH_REST_COUNTS[sh_degree]
    return {
        "xyz": ("x", "y", "z"),
        "f_dc": ("f_dc_0", "f_dc_1", "f_dc_2"),
        "f_rest": tuple(f"f_rest_{i}" for i in range(rest)),
        "opacity": ("opacity",),
        "scale": ("scale_0", "scale_1", "scale_2"),
        "rot": ("rot_0", "rot_1", "rot_2", "rot_3"),
    }


def required_properties(sh_degree: int) -> set[str]:
    return {name for names in property_groups(sh_degree).values() for name in names}


def cloud_properties(cloud: GaussianCloud) -> Properties:
    """The properties the reference PLY writer would write for ``cloud`` (normals included)."""
    _, records = ply_bytes(cloud)
    return {name: np.ascontiguousarray(records[name]) for name in records.dtype.names}


class OutputError(ValueError):
    """An output file breaks the PLY contract; the message says how."""


def read_output_ply(path: Path, sh_degree: int | None) -> Properties:
    """Read a decoder's PLY under the contract: binary little-endian, float32, and (when the SH
    degree is known) exactly the contract's property set."""
    from plyfile import PlyData, PlyParseError

    try:
        ply = PlyData.read(str(path))
    except (PlyParseError, ValueError, EOFError, IndexError, KeyError, TypeError, OSError) as exc:
        raise OutputError(f"output is not a readable PLY ({_first_line(exc)})") from None
    if ply.text or ply.byte_order != "<":
        raise OutputError("output PLY is not binary_little_endian")
    vertex = next((el for el in ply.elements if el.name == "vertex"), None)
    if vertex is None:
        raise OutputError("output PLY has no 'vertex' element")
    types = {p.name: p.val_dtype for p in vertex.properties}
    wrong = sorted(name for name, dtype in types.items() if np.dtype(dtype) != np.dtype("<f4"))
    if wrong:
        raise OutputError(f"output PLY properties are not float32: {', '.join(wrong[:4])}")
    if sh_degree is not None:
        check_property_set(set(types), sh_degree)
    return {name: np.asarray(vertex.data[name], dtype=np.float32) for name in types}


def check_property_set(names: set[str], sh_degree: int) -> None:
    """The contract's property set: the groups for ``sh_degree``, normals all three or none."""
    required = required_properties(sh_degree)
    missing = sorted(required - names)
    extra = sorted(names - required - set(NORMALS))
    if missing:
        raise OutputError(f"output lacks {', '.join(missing[:6])}"
                          f"{' ...' if len(missing) > 6 else ''} (SH degree {sh_degree})")
    if extra:
        raise OutputError(f"output has properties the contract does not allow: "
                          f"{', '.join(extra[:6])}{' ...' if len(extra) > 6 else ''} "
                          f"(SH degree {sh_degree})")
    present_normals = [n for n in NORMALS if n in names]
    if present_normals and len(present_normals) != 3:
        raise OutputError("output has some but not all of nx, ny, nz")


def read_expected(path: Path, expected: Expected) -> Properties:
    """A vector's expected output: the reference PLY, or an ``.npz`` of the same properties."""
    if path.suffix == ".npz":
        with np.load(path) as archive:
            return {name: np.asarray(archive[name], np.float32) for name in archive.files}
    return read_output_ply(path, expected.sh_degree)


def write_npz(path: Path, properties: Properties) -> None:
    """An ``.npz`` whose bytes depend only on the arrays (``numpy.savez`` stamps the time)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        for name in sorted(properties):
            array = io.BytesIO()
            np.lib.format.write_array(array, np.ascontiguousarray(properties[name], "<f4"),
                                      allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, array.getvalue())
    path.write_bytes(buffer.getvalue())


def compare(got: Properties, want: Properties, expected: Expected) -> str | None:
    """Why ``got`` differs from ``want`` beyond the tolerances, or None when it does not.

    ``want`` holds exactly the rows of this decode; rows before ``expected.sketch_gaussians`` are
    sketch rows, the others patch rows, each with their own tolerances ([R-96]).
    """
    n = len(want["x"])
    count = len(got["x"])
    if count != n:
        return f"{count} Gaussians, expected {n}"
    for name in NORMALS:
        if name in got and np.any(got[name] != 0):
            row = int(np.flatnonzero(got[name] != 0)[0])
            return f"{name}[{row}] = {got[name][row]!r}, normals must be 0"
    split = min(expected.sketch_gaussians, n)
    for group, names in property_groups(expected.sh_degree).items():
        for name in names:
            for kind, rows in (("sketch", slice(0, split)), ("patch", slice(split, n))):
                problem = _compare_column(got[name][rows], want[name][rows],
                                          expected.tolerance(kind, group))
                if problem is not None:
                    row, detail = problem
                    return f"{name}[{rows.start + row}] ({kind}) {detail}"
    return None


def _compare_column(got: np.ndarray, want: np.ndarray, tol) -> tuple[int, str] | None:
    if not len(want):
        return None
    g = got.astype(np.float64)
    w = want.astype(np.float64)
    finite = np.isfinite(g)
    if not finite.all():
        row = int(np.argmin(finite))
        return row, f"= {got[row]!r}, not finite"
    bound = tol.abs + tol.ulps * ulp32(want) if tol.ulps else np.full(len(w), tol.abs)
    bad = np.abs(g - w) > bound
    if not bad.any():
        return None
    row = int(np.argmax(bad))
    return row, (f"= {float(got[row])!r}, expected {float(want[row])!r} "
                 f"(tolerance abs {tol.abs:g}, {tol.ulps} ulp)")


_BELOW_MAX = np.nextafter(np.finfo(np.float32).max, np.float32(0))


def ulp32(values: np.ndarray) -> np.ndarray:
    """The spacing of binary32 numbers at ``|values|`` (float64); at the largest finite binary32,
    the spacing below it (``numpy.spacing`` says infinity there)."""
    magnitude = np.minimum(np.abs(values.astype(np.float32)), _BELOW_MAX)
    return np.spacing(magnitude).astype(np.float64)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__
