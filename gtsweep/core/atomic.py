"""Atomic file writes: a reader sees the old file or the whole new one, never a half-written one."""
from __future__ import annotations

import errno
import os
import secrets
from pathlib import Path
from typing import IO, Callable


def current_umask() -> int:
    """The process umask, read without changing it where Linux allows (``os.umask`` alone must set it)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def respect_umask(path: str | os.PathLike, directory: bool = False) -> None:
    """Give ``path`` the mode a plain ``open`` (``mkdir``) would: ``tempfile`` creates files 0600 (folders 0700)."""
    os.chmod(path, (0o777 if directory else 0o666) & ~current_umask())


def write_atomically(path: str | os.PathLike, content: str | Callable[[IO[bytes]], None]) -> None:
    """Write ``content`` (text, or a function that writes to a binary file) to ``path`` via a temporary file in
    the same directory and ``os.replace``; the file gets the mode the umask gives; a failure leaves no temporary
    file behind."""
    path = Path(path)
    try:
        _write(path, content)
    except OSError as e:  # a full disk or a write error says which file (``write`` itself names none)
        if e.filename is None and e.errno is not None:
            raise OSError(e.errno, e.strerror, str(path)) from None
        raise


def _create_temporary(path: Path) -> tuple[int, Path]:
    """A new file of our own next to ``path`` (``.<name>.<random>.tmp``, opened exclusively), created with mode
    0666 so that the kernel applies the umask as a plain ``open`` does; ``path``'s folder is made when missing."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0) | getattr(os, "O_NOFOLLOW", 0)
    made = False
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
        except FileNotFoundError:
            if made:
                raise
            path.parent.mkdir(parents=True, exist_ok=True)
            made = True
    raise FileExistsError(errno.EEXIST, "no unused temporary file name", str(path))


def _write(path: Path, content) -> None:
    fd, tmp = _create_temporary(path)
    try:
        with os.fdopen(fd, "wb") as f:
            if isinstance(content, str):
                f.write(content.encode())
            else:
                content(f)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
