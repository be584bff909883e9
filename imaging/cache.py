"""A cache of renders on disk, so that judging many files against one reference renders it once.

``spcodec eval X.spc --reference ORIG.ply`` renders the reference at the same cameras every time
it judges a file of the same scene: half of its rendering. :class:`RenderCache` keeps those
renders (and the cameras they were made at) in one file per framing, named by a key that
covers everything the pixels depend on (:func:`cache_key`):

* the reference's *content* (:func:`cloud_digest`: every array of the cloud as rendered, so a
  copy or a renamed file hits and a rewritten one misses, whatever its path or date);
* how the cameras were made (views, resolution, up, seed, the close-up distance and resolution);
* every render setting (background, low-pass, antialiased, near plane, alpha clamp, tiling);
* the renderer: backend and device, the torch, numpy and scipy versions, and a digest of the
  source of the modules that place cameras and draw pixels (:func:`code_fingerprint`), so a
  changed renderer misses instead of serving stale pictures.

A hit therefore gives the very bits a render would; a file that cannot be read back whole (cut
short, overwritten, a flipped byte: every member of the ``.npz`` carries a CRC-32 that reading
checks) or that holds another key is ignored and replaced. Files are written to a temporary name
in the same folder and renamed into place, so a reader never sees half a file and concurrent
runs never corrupt one. The folder is :func:`default_cache_dir` (``$XDG_CACHE_HOME/spcodec/renders``,
else ``~/.cache/spcodec/renders``); it is kept under :data:`MAX_CACHE_BYTES`, dropping the
entries used least recently. numpy only (no torch).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from spcodec.cloud import GaussianCloud

from .cameras import Camera

CACHE_FORMAT = 1
"""Version of the entry layout; part of every key."""

MAX_CACHE_BYTES = 2 << 30
"""The cache folder is trimmed to this many bytes after each write (least recently used first).
One evaluation at the default settings stores about 140 MB (8 views at 400 px, 16 at 800 px,
float32 RGB)."""

_STALE_TEMP_SECONDS = 3600.0
"""Temporary files older than this are left-overs of an interrupted write, removed when trimming."""


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/spcodec/renders``, or ``~/.cache/spcodec/renders`` without it."""
    base = os.environ.get("XDG_CACHE_HOME")
    root = Path(base).expanduser() if base else Path.home() / ".cache"
    return root / "spcodec" / "renders"


def cloud_digest(cloud: GaussianCloud) -> str:
    """SHA-256 of a cloud's content: every array's dtype, shape and bytes, in field order."""
    digest = hashlib.sha256()
    for name in ("means", "scales", "quats", "opacities", "sh_dc", "sh_rest"):
        array = np.ascontiguousarray(getattr(cloud, name))
        digest.update(f"{name}:{array.dtype.str}:{array.shape};".encode())
        if array.size:
            digest.update(memoryview(array.reshape(-1)).cast("B"))
    return digest.hexdigest()


def code_fingerprint(*modules: ModuleType) -> str:
    """SHA-256 of the source files of ``modules`` (a package counts with every ``.py`` file in
    its folder), so editing any of them changes the keys that include it."""
    digest = hashlib.sha256()
    for module in modules:
        path = Path(getattr(module, "__file__", "") or "")
        files = sorted(path.parent.glob("*.py")) if path.name == "__init__.py" else [path]
        for file in files:
            try:
                digest.update(file.name.encode() + b"\0" + file.read_bytes() + b"\0")
            except OSError:  # no source on disk: the module's name and version must do
                digest.update(f"{module.__name__}:{getattr(module, '__version__', '')}".encode())
    return digest.hexdigest()


def cache_key(parts: dict[str, Any]) -> str:
    """The key of an entry: SHA-256 of ``parts`` (JSON-able) as canonical JSON."""
    text = json.dumps({"format": CACHE_FORMAT, **parts}, sort_keys=True, separators=(",", ":"),
                      allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass
class CachedRenders:
    """The renders of one framing: its cameras, their images (V, H, W, 3) float32, and any notes
    to repeat when they are served again (e.g. a view-sampling warning)."""

    cameras: list[Camera]
    images: np.ndarray
    notes: list[str] = field(default_factory=list)
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    """Further arrays stored with the entry (e.g. the point the close-ups dolly towards)."""


class RenderCache:
    """Entries in ``folder``, one ``<key>.npz`` file each (see the module docstring)."""

    def __init__(self, folder: str | os.PathLike, max_bytes: int = MAX_CACHE_BYTES) -> None:
        self.folder = Path(folder)
        self.max_bytes = max_bytes

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.npz"

    def get(self, key: str) -> CachedRenders | None:
        """The entry stored under ``key``, or None when there is none or it cannot be read back
        whole (a damaged file is removed, so the next write replaces it)."""
        path = self.path(key)
        try:
            with np.load(path, allow_pickle=False) as data:
                entry = _unpack(key, data)
        except FileNotFoundError:
            return None
        except Exception:  # noqa: BLE001 - whatever the damage (bad zip, CRC, header), a miss
            self._discard(path)
            return None
        try:
            os.utime(path)  # most recently used: trimmed last
        except OSError:
            pass
        return entry

    def put(self, key: str, entry: CachedRenders) -> str | None:
        """Store ``entry`` under ``key`` atomically; the reason in one line when it could not be
        written (a read-only or full disk: the evaluation goes on without the cache)."""
        arrays = _pack(key, entry)
        tmp = None
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=self.folder)
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **arrays)
            os.replace(tmp, self.path(key))
            tmp = None
        except OSError as exc:
            return f"the render cache in {self.folder} was not written ({exc.strerror or exc})"
        finally:
            if tmp is not None:
                self._discard(Path(tmp))
        self.trim(keep=self.path(key))
        return None

    def trim(self, keep: Path | None = None) -> None:
        """Remove the least recently used entries until the folder holds at most ``max_bytes``
        (never ``keep``), and temporary files an interrupted write left behind."""
        now = time.time()
        entries = []
        try:
            listing = list(os.scandir(self.folder))
        except OSError:
            return
        for item in listing:
            try:
                stat = item.stat()
            except OSError:
                continue
            if item.name.endswith(".tmp"):
                if now - stat.st_mtime > _STALE_TEMP_SECONDS:
                    self._discard(Path(item.path))
            elif item.name.endswith(".npz"):
                entries.append((stat.st_mtime, stat.st_size, Path(item.path)))
        total = sum(size for _, size, _ in entries)
        for _, size, path in sorted(entries):
            if total <= self.max_bytes:
                break
            if keep is not None and path == keep:
                continue
            self._discard(path)
            total -= size

    @staticmethod
    def _discard(path: Path) -> None:
        try:
            path.unlink()
        except OSError:
            pass


def _pack(key: str, entry: CachedRenders) -> dict[str, np.ndarray]:
    cams = entry.cameras
    return {
        "key": np.array(key),
        "images": np.ascontiguousarray(entry.images, dtype=np.float32),
        "size": np.array([[c.width, c.height] for c in cams], dtype=np.int64).reshape(-1, 2),
        "intrinsics": np.array([[c.fx, c.fy, c.cx, c.cy] for c in cams],
                               dtype=np.float64).reshape(-1, 4),
        "world_to_camera": np.array([c.world_to_camera for c in cams],
                                    dtype=np.float64).reshape(-1, 4, 4),
        "names": np.array([c.name for c in cams], dtype=np.str_),
        "notes": np.array(entry.notes, dtype=np.str_),
        **{f"extra_{name}": np.asarray(value) for name, value in entry.extra.items()},
    }


def _unpack(key: str, data) -> CachedRenders:
    if str(data["key"][()]) != key:
        raise ValueError("the entry holds another key")
    images, size, intrinsics = data["images"], data["size"], data["intrinsics"]
    w2c, names = data["world_to_camera"], data["names"]
    count = len(images)
    if images.dtype != np.float32 or images.ndim != 4 or images.shape[3] != 3 or not all(
            len(a) == count for a in (size, intrinsics, w2c, names)):
        raise ValueError("the entry's arrays do not fit together")
    cameras = [Camera(int(size[i, 0]), int(size[i, 1]), *map(float, intrinsics[i]), w2c[i],
                      str(names[i])) for i in range(count)]
    if any((c.height, c.width) != images.shape[1:3] for c in cameras):
        raise ValueError("the entry's images and cameras differ in size")
    extra = {name[len("extra_"):]: data[name] for name in data.files if name.startswith("extra_")}
    return CachedRenders(cameras, images, [str(n) for n in data["notes"]], extra)
