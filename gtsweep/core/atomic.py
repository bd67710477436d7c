"""Atomic file writes: a reader sees the old file or the whole new one, never a half-written one."""
from __future__ import annotations

import os
import tempfile
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


def _write(path: Path, content) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            if isinstance(content, str):
                f.write(content.encode())
            else:
                content(f)
        respect_umask(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
