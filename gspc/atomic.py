"""Writing an output where the user pointed: a regular file is replaced atomically (readers never see a
half-written file, a failed write leaves no debris); a character device or named pipe is written as a
stream; anything else is refused in one line (issue 26: ``-o /dev/null`` once replaced the device node with
a regular file, and ``-o dir/name/`` silently wrote ``dir/name``)."""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from gspc.errors import InputError


def check_output_path(path: str | os.PathLike) -> None:
    """InputError for an output path that cannot name a file: it ends in a slash or names a folder, a block
    device or a socket. Callers check before any work, so a long encode does not end in this refusal."""
    text = os.fspath(path)
    if text.endswith("/") or text.endswith(os.sep):
        raise InputError(f"{text}: an output path ending in '/' names a folder; name the output file")
    try:
        mode = os.stat(text).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise InputError(f"{text}: cannot use as output ({e.strerror})") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{text} is a folder; name the output file")
    if not (stat.S_ISREG(mode) or stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)):
        raise InputError(f"{text} is neither a regular file, a character device nor a named pipe; refused")


def _is_stream(path: str) -> bool:
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None], fsync: bool = False) -> None:
    """Call ``write(f)`` on a temporary file beside ``path``, then rename it over ``path``; or, where
    ``path`` is a character device (/dev/null, a terminal) or a named pipe, on ``path`` opened as a stream.

    A symbolic link to a regular file stays a link: its target is replaced. The file gets the usual 0644
    permissions (mkstemp creates 0600). Raises InputError when the output directory does not exist or the
    path cannot name an output (check_output_path), so the CLI reports it in one line.
    """
    import tempfile  # here, not at the top: the CLI imports this module at start (bench/startup.md)

    check_output_path(path)
    text = os.fspath(path)
    if _is_stream(text):
        # Opening a named pipe blocks until a reader opens it, as a shell's redirection does.
        with open(text, "wb") as f:
            write(f)
        return
    target = Path(os.path.realpath(text)) if os.path.islink(text) else Path(text)
    if not target.parent.is_dir():
        raise InputError(f"{text}: output directory {target.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes, fsync: bool = False) -> None:
    atomic_write(path, lambda f: f.write(data), fsync=fsync)
