"""Atomic output files: write to a temporary name in the target folder, then rename.

A failure part-way (a full disk, an exception in the producer, Ctrl-C) leaves the destination as it
was: either absent or the previous complete file, never half written.

What a user names is written, never replaced: ``-`` is standard output; an existing path that is
not a regular file (``/dev/stdout``, ``/dev/null``, a FIFO) is opened and written through, since
renaming over it would turn a device or pipe into a plain file; a symbolic link to a file is
followed, and the file it points to is replaced atomically, so the link stays a link.
"""

from __future__ import annotations

import io
import os
import stat
import sys
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

from .errors import UsageError

STDOUT = "-"
"""The output name that means standard output."""


def is_stdout(path: str | os.PathLike) -> bool:
    return str(path) == STDOUT


def refuse_same_file(output: str | os.PathLike, *inputs: str | os.PathLike) -> None:
    """A one-line UsageError when ``output`` is one of ``inputs`` (writing it would destroy what
    is being read), by name or through links."""
    if is_stdout(output):
        return
    for source in inputs:
        if source is None or is_stdout(source):
            continue
        try:
            same = os.path.samefile(output, source)
        except OSError:  # the output does not exist yet (or the input does not): not the same
            same = False
        if same:
            raise UsageError(f"{output} is also the input: writing it would destroy the input; "
                             "choose another output name")


def check_writable(path: str | os.PathLike) -> Path:
    """Fail early, with one line naming ``path``, when it cannot be created (before hours of work).

    Permission bits are not enough: root passes ``os.access`` everywhere, and /proc, read-only
    mounts or a full quota refuse new files all the same. So the folder is probed by creating (and
    removing) the kind of temporary file :func:`atomic_write` will create there.
    """
    if is_stdout(path):
        return Path(STDOUT)
    target = _check_target(path)
    if _written_through(target):
        return target
    target = _resolved(target)
    _probe(target.parent, target.name, target)
    return Path(path)


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

    Errors name ``path``, never the temporary file the user did not ask for. ``-``, devices and
    pipes are written through, links followed (see the module docstring).
    """
    if is_stdout(path):  # produced in memory first: a reader that leaves early then shows as
        if callable(data):  # BrokenPipeError, whatever the producer writes with
            buffer = io.BytesIO()
            data(buffer)
            data = buffer.getvalue()
        _write_stream(sys.stdout.buffer, data)
        return Path(STDOUT)
    target = _check_target(path)
    if _written_through(target):
        try:
            with open(target, "wb") as out:
                _write_stream(out, data)
        except OSError as exc:  # /dev/full: ENOSPC with no file name; name the user's path
            if exc.filename is None:
                raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from exc
            raise
        return target
    asked, target = target, _resolved(target)
    fd, tmp = _temporary(target.parent, target.name, asked)
    try:
        with os.fdopen(fd, "wb") as out:
            _write_stream(out, data)
            os.fsync(out.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, target)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError) and exc.filename in (None, tmp):  # e.g. a full disk
            raise OSError(exc.errno, exc.strerror or str(exc), str(asked)) from exc
        raise
    return asked


def _write_stream(out: BinaryIO, data: bytes | Callable[[BinaryIO], None]) -> None:
    if callable(data):
        data(out)
    else:
        out.write(data)
    out.flush()


def _written_through(target: Path) -> bool:
    """An existing path that is not a regular file (after links): a device, FIFO or socket."""
    try:
        mode = os.stat(target).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode)


def _resolved(target: Path) -> Path:
    """Where a (chain of) symbolic link(s) points; ``target`` itself when it is no link."""
    if not target.is_symlink():
        return target
    return Path(os.path.realpath(target))


def _check_target(path: str | os.PathLike) -> Path:
    """The checks that need no file to be created."""
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if target.is_dir():
        raise UsageError(f"cannot write {target}: it is a directory")
    if not folder.is_dir():
        blocker = _nearest_existing(folder)
        if blocker is not None and not blocker.is_dir():
            raise UsageError(f"cannot write {target}: {blocker} is a file, not a folder")
        raise UsageError(f"cannot write {target}: folder {folder} does not exist")
    if target.exists() and not os.access(target, os.W_OK):
        raise UsageError(f"cannot write {target}: the file is not writable")
    return target


def _nearest_existing(folder: Path) -> Path | None:
    """The deepest existing ancestor of ``folder`` (itself included): a file there is why the
    folder cannot exist, which "does not exist" would hide."""
    for candidate in (folder, *folder.parents):
        if candidate.exists():
            return candidate
    return None


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
