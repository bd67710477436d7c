"""Seeds that are the same in every process and run."""
from __future__ import annotations

import zlib


def stable_seed(*parts) -> int:
    """A seed derived from ``parts`` that is the same in every process and run (unlike ``hash``)."""
    return zlib.crc32(":".join(str(p) for p in parts).encode())
