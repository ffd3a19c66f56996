"""Output paths checked before the work starts, and OS errors as messages that name the path.

Commands that write files check ``--out`` first (:func:`check_output_file`,
:func:`check_output_dir`), so a bad path fails in a second with a message instead of after minutes
of work with a traceback. What can only fail while writing (a full disk, a device that refuses
writes) is turned into a message by :func:`describe_os_error`, which the ``pcvfe`` entry point
applies to every ``OSError``. Nothing here deletes what was already written.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

_REASONS = {
    errno.ENOSPC: "no space left on the device (the disk is full)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOTDIR: "a part of the path is a file, not a folder",
    errno.EISDIR: "it is a folder, not a file",
    errno.EEXIST: "it already exists",
    errno.ENOENT: "no such file or folder",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EIO: "input/output error of the device",
    errno.EFBIG: "the file is too large for the device",
}
_HINTS = {
    errno.ENOSPC: "free some space or write somewhere else",
    errno.EDQUOT: "free some space or write somewhere else",
    errno.EACCES: "choose a folder you can write to",
    errno.EPERM: "choose a folder you can write to",
    errno.EROFS: "choose a writable place",
}


class OutputPathError(ValueError):
    """An output path that cannot be used; the message names the path, the reason and a fix."""


def write_failed(exc: OSError, option: str, path: str | os.PathLike) -> OutputPathError:
    """The error to raise when writing ``path`` (given as ``option``) failed with ``exc``."""
    reason = _REASONS.get(exc.errno) or exc.strerror or str(exc)
    hint = _HINTS.get(exc.errno)
    where = f" ({exc.filename})" if exc.filename and str(exc.filename) != str(path) else ""
    text = f"{option} {path}: could not write{where}: {reason}"
    return OutputPathError(f"{text}; {hint}" if hint else text)


def describe_os_error(exc: OSError, what: str = "") -> str:
    """One line for an ``OSError``: ``[what ]path: reason[; hint]``.

    ``exc.filename`` names the path where the OS reported one; an error without a path and
    without an errno (a message written by this project) is returned as it is.
    """
    if exc.errno is None:
        return f"{what} {exc}".strip()
    reason = _REASONS.get(exc.errno) or exc.strerror or os.strerror(exc.errno)
    hint = _HINTS.get(exc.errno)
    path = exc.filename if exc.filename is not None else "(no path given by the OS)"
    text = f"{what} {path}: {reason}".strip()
    return f"{text}; {hint}" if hint else text


def _nearest_existing(path: Path) -> Path:
    """``path`` itself or its nearest ancestor that exists."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")


def _check_creatable(folder: Path, option: str, target: Path) -> None:
    """``folder`` is, or can be created as, a folder that this process can write in."""
    existing = _nearest_existing(folder)
    if not existing.is_dir():
        raise OutputPathError(
            f"{option} {target}: {existing} is a file, so no folder can be made under it; "
            "choose another path"
        )
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputPathError(
            f"{option} {target}: no permission to write in {existing}; choose another place"
        )


def check_output_file(path: str | os.PathLike, option: str = "--out") -> Path:
    """Check, without writing anything, that a file can be written at ``path``; returns it.

    An existing file is fine (it will be replaced); a folder at ``path``, a file among its
    parents or a place without write permission raise :class:`OutputPathError`.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{option} {path}: is a folder; name a file in it instead")
    _check_creatable(path.parent, option, path)
    return path


def check_output_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """Check, without writing anything, that ``path`` is or can become a writable folder.

    An existing file at ``path``, a file among its parents or a place without write permission
    raise :class:`OutputPathError`. Returns the path.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(
            f"{option} {path}: exists and is a file; {option} takes a folder (choose another name)"
        )
    _check_creatable(path, option, path)
    return path


def os_error_text(exc: OSError, path: str | Path) -> str:
    """``"path: reason[; hint]"`` for an OS error met while writing ``path`` (the wording of
    :func:`describe_os_error`)."""
    if exc.errno is None:
        return f"{path}: {exc}"
    return describe_os_error(OSError(exc.errno, exc.strerror, str(path)))
