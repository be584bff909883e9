"""Atomic output files: write to a temporary name in the target folder, then rename.

A failure part-way (a full disk, an exception in the producer, Ctrl-C) leaves the destination as it
was: either absent or the previous complete file, never half written.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

from .errors import UsageError


def check_writable(path: str | os.PathLike) -> Path:
    """Fail early, with one line naming ``path``, when it cannot be created (before hours of work).

    Permission bits are not enough: root passes ``os.access`` everywhere, and /proc, read-only
    mounts or a full quota refuse new files all the same. So the folder is probed by creating (and
    removing) the kind of temporary file :func:`atomic_write` will create there.
    """
    target = _check_target(path)
    _probe(target.parent, target.name, target)
    return target


def check_writable_folder(path: str | os.PathLike) -> Path:
    """Fail early, with one line naming ``path``, when files cannot be written into that folder.

    Nothing is created: a missing folder passes when its nearest existing ancestor is a writable
    folder, and whoever writes the first file creates it (so a failed run leaves no empty folder).
    """
    folder = Path(path)
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise UsageError(f"cannot write into {folder}: {existing} is not a folder")
    _probe(existing, folder.name or "output", folder)
    return folder


def atomic_write(path: str | os.PathLike, data: bytes | Callable[[BinaryIO], None]) -> Path:
    """Write ``data`` (bytes, or a function that writes into a binary file) to ``path`` atomically.

    Errors name ``path``, never the temporary file the user did not ask for.
    """
    target = _check_target(path)
    fd, tmp = _temporary(target.parent, target.name, target)
    try:
        with os.fdopen(fd, "wb") as out:
            if callable(data):
                data(out)
            else:
                out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, target)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError) and exc.filename in (None, tmp):  # e.g. a full disk
            raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from exc
        raise
    return target


def _check_target(path: str | os.PathLike) -> Path:
    """The checks that need no file to be created."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if target.is_dir():
        raise UsageError(f"cannot write {target}: it is a directory")
    if not folder.is_dir():
        raise UsageError(f"cannot write {target}: folder {folder} does not exist")
    if target.exists() and not os.access(target, os.W_OK):
        raise UsageError(f"cannot write {target}: the file is not writable")
    return target


def _temporary(folder: Path, name: str, what: Path) -> tuple[int, str]:
    """A new hidden ``.NAME.XXXX.part`` file in ``folder``: (descriptor, path).

    A failure names ``what``, the path the user asked for, not the temporary file.
    """
    try:
        return tempfile.mkstemp(prefix=f".{name}.", suffix=".part", dir=folder)
    except OSError as exc:
        raise UsageError(f"cannot write {what}: cannot create files in {folder} "
                         f"({exc.strerror or exc})") from None


def _probe(folder: Path, name: str, what: Path) -> None:
    """Create and remove a temporary file in ``folder``: the only sure test that writing works."""
    fd, tmp = _temporary(folder, name, what)
    os.close(fd)
    os.unlink(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
