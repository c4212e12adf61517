"""Files written whole or not at all: a kill or a full disk in the middle of a write leaves
the file as it was before (checkpoints, result.npz, steps.csv and fields.xdmf rewound on a
resume or after a failed write).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np


def replace_atomically(path: Path, write) -> None:
    """``write(stream)`` into a temporary file beside ``path`` (binary), flush it to disk, then
    rename it onto ``path``: a kill at any moment leaves either the old file or the new one."""
    temporary = path.with_name(f".{path.name}.tmp")
    try:
        with open(temporary, "wb") as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:       # a full disk, say: no partial file left behind
        temporary.unlink(missing_ok=True)
        raise


def replace_text(path: Path, text: str) -> None:
    replace_atomically(path, lambda stream: stream.write(text.encode()))


def replace_copy(source: Path, target: Path) -> None:
    """Copy ``source`` onto ``target`` atomically."""
    import shutil

    def copy(stream):
        with open(source, "rb") as original:
            shutil.copyfileobj(original, stream, 1 << 20)
    replace_atomically(target, copy)


def savez(stream, arrays) -> None:
    """np.savez into memory first, then to ``stream``: a failed write leaves no half-closed
    zip file behind (whose clean-up prints a traceback)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    stream.write(buffer.getbuffer())
