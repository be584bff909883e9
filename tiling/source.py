"""Scene input in chunks of rows, so that peak memory follows the chunk and not the file.

Inputs of fixed-size records are memory-mapped, and only the rows of the chunk asked for are turned
into a :class:`~spcodec.cloud.GaussianCloud`; the operating system pages the rest in and out:
a binary INRIA PLY (plyfile finds where its vertex records start and their layout) and an
antimatter15 ``.splat`` (32-byte records from the first byte). Every other input the format
registry reads (SPZ, SOG, ``.ksplat``, a PlayCanvas compressed PLY, an ASCII PLY) is loaded whole
and then handed out in the same chunks: SPZ is one gzip stream of columns and the others are
packed or text, so their rows cannot be addressed in place without a reader of their own
(``.ksplat``'s sections of fixed-size records could be: a reader by section is future work).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from spcodec.cloud import GaussianCloud, sh_degree_for_rest_count
from spcodec.errors import FormatError, UsageError
from spcodec.ply import cloud_from_vertex, inria_rest_names


class SceneSource:
    """Rows ``0..count`` of a scene, read a chunk at a time."""

    count: int
    sh_degree: int
    mapped: bool
    """True when rows are read in place (memory-mapped), False when the scene was loaded whole."""

    def positions(self, start: int, stop: int) -> np.ndarray:
        """Centres of rows ``start..stop`` as (n, 3) float32 (pass 1 reads nothing else)."""
        raise NotImplementedError

    def chunk(self, start: int, stop: int) -> GaussianCloud:
        """Rows ``start..stop`` as a cloud (a copy, independent of the source)."""
        raise NotImplementedError

    def chunks(self, size: int) -> Iterator[tuple[int, GaussianCloud]]:
        """``(start, cloud)`` for consecutive chunks of at most ``size`` rows."""
        for start in range(0, self.count, size):
            yield start, self.chunk(start, min(self.count, start + size))

    def all_positions(self, size: int, chunk_done: Callable[[], object] = lambda: None
                      ) -> np.ndarray:
        """Every centre, read ``size`` rows at a time (12 bytes per Gaussian in memory);
        ``chunk_done`` is called after each chunk (a progress stage's ``update``)."""
        out = np.empty((self.count, 3), np.float32)
        for start in range(0, self.count, size):
            stop = min(self.count, start + size)
            out[start:stop] = self.positions(start, stop)
            chunk_done()
        return out


class MappedRecords(SceneSource):
    """Fixed-size records at ``offset`` in a file, mapped one chunk at a time.

    Each chunk maps only its own rows and unmaps them when done: file pages that stay mapped
    count in the process's resident memory, so a map of the whole file would make the peak
    follow the file after all (the pages are reclaimable, but the measure would not say so).
    """

    def __init__(self, filename: str, offset: int, dtype: np.dtype, count: int) -> None:
        self.filename, self.offset, self.dtype, self.count = filename, offset, dtype, count
        self.mapped = True

    def _rows(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start..stop``, mapped for as long as the caller holds them."""
        if stop <= start:
            return np.zeros(0, self.dtype)
        return np.memmap(self.filename, self.dtype, mode="r",
                         offset=self.offset + start * self.dtype.itemsize, shape=(stop - start,))


class MappedPly(MappedRecords):
    """A binary INRIA PLY's vertex records."""

    def __init__(self, vertex: np.memmap, name: str) -> None:
        super().__init__(vertex.filename, vertex.offset, vertex.dtype, len(vertex))
        self.rest = inria_rest_names(set(vertex.dtype.names or ()), name)
        self.sh_degree = sh_degree_for_rest_count(len(self.rest) // 3)

    def positions(self, start: int, stop: int) -> np.ndarray:
        rows = self._rows(start, stop)
        return np.stack([np.asarray(rows[p], np.float32) for p in ("x", "y", "z")], axis=1)

    def chunk(self, start: int, stop: int) -> GaussianCloud:
        return cloud_from_vertex(self._rows(start, stop), self.rest)


class MappedSplat(MappedRecords):
    """An antimatter15 ``.splat``: 32-byte records, no header, no SH beyond DC."""

    def __init__(self, path: Path) -> None:
        from spcodec.formats import splat
        from spcodec.formats.common import check_count

        size = path.stat().st_size
        if size % splat.RECORD.itemsize:
            raise FormatError(f"{path}: {size} bytes is not a whole number of 32-byte .splat "
                              "records", "truncated")
        super().__init__(str(path), 0, splat.RECORD, size // splat.RECORD.itemsize)
        check_count(str(path), self.count)
        self.sh_degree = 0

    def positions(self, start: int, stop: int) -> np.ndarray:
        return np.array(self._rows(start, stop)["position"], np.float32)

    def chunk(self, start: int, stop: int) -> GaussianCloud:
        from spcodec.formats.splat import cloud_from_records

        return cloud_from_records(np.array(self._rows(start, stop)))  # a copy: the map closes


class LoadedScene(SceneSource):
    """A scene read whole by the format registry, handed out in chunks all the same."""

    def __init__(self, cloud: GaussianCloud) -> None:
        self.cloud = cloud
        self.count = len(cloud)
        self.sh_degree = cloud.sh_degree
        self.mapped = False

    def positions(self, start: int, stop: int) -> np.ndarray:
        return self.cloud.means[start:stop]

    def chunk(self, start: int, stop: int) -> GaussianCloud:
        return self.cloud.subset(slice(start, stop))


def open_source(path: str | os.PathLike) -> SceneSource:
    """The scene at ``path``: memory-mapped when it is a binary INRIA PLY or a ``.splat``, else
    loaded whole.

    UsageError for a missing file, FormatError (one line) for a file no reader takes or a PLY
    without the 3DGS properties.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such file")
    vertex = _mapped_vertex(path)
    if vertex is not None:
        return MappedPly(vertex, str(path))
    from spcodec.formats import detect, read_scene

    fmt = detect(path)
    if fmt is not None and fmt.key == "splat":
        return MappedSplat(path)
    return LoadedScene(read_scene(path))


def _mapped_vertex(path: Path) -> np.memmap | None:
    """The memory-mapped vertex records of a binary INRIA PLY; None for any other file (whose
    reader then gives the error, or reads it whole)."""
    with open(path, "rb") as fh:
        if fh.read(4) != b"ply\n" and not _is_ply_crlf(path):
            return None
    from plyfile import PlyData, PlyParseError

    try:
        ply = PlyData.read(str(path), mmap="r")
    except (PlyParseError, ValueError, EOFError, IndexError, KeyError, TypeError):
        return None
    elements = {el.name: el for el in ply.elements}
    if "vertex" not in elements or "chunk" in elements:  # compressed PLY: packed, read whole
        return None
    vertex = elements["vertex"].data
    return vertex if isinstance(vertex, np.memmap) else None


def _is_ply_crlf(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(5) == b"ply\r\n"
