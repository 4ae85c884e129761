"""One atomic file writer: a reader never sees a half-written file, a failed write leaves the old file untouched."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator, Union

FILE_MODE = 0o644  # what a plain open() gives under the usual umask; mkstemp alone would leave 0600


@contextlib.contextmanager
def atomic_path(path: Union[str, Path]) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for a writer that needs a file name (ffmpeg, PIL); on success it gets
    FILE_MODE and is renamed onto ``path`` (os.replace); on any exception it is removed and ``path`` is left as it
    was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_open(path: Union[str, Path], binary: bool = False) -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing (atomic_path); the data is synced before the rename."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())


def atomic_write(path: Union[str, Path], data: Union[str, bytes]) -> Path:
    """Write ``data`` (text or bytes) to ``path`` atomically (atomic_open); returns the path."""
    with atomic_open(path, binary=isinstance(data, bytes)) as f:
        f.write(data)
    return Path(path)
