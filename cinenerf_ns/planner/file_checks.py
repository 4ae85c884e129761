"""What is wrong with a path a user named as an input file: not found, a broken link, a link loop, a folder, a FIFO,
a device or socket. ``Path.exists()`` answers False for a symlink loop and ``is_file()`` False for a FIFO; both would
otherwise be reported as "not found" (and opening a FIFO blocks until something writes to it)."""
from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import Optional, Union

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"))


def path_problem(path: Union[str, Path], folder_ok: bool = False) -> Optional[str]:
    """None when ``path`` is a regular file (or, with ``folder_ok``, a folder); else a phrase to follow the path in
    a message: 'was not found', 'is a symbolic link loop', 'is a FIFO (named pipe), not a regular file', ..."""
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "is a symbolic link loop (it never reaches a file)"
        if e.errno == errno.ENOENT and os.path.islink(path):
            return f"is a broken symbolic link (to {os.readlink(path)}, which does not exist)"
        if e.errno == errno.ENOENT:
            return "was not found"
        if e.errno == errno.ENAMETOOLONG:
            return "is a name too long for the file system"
        return f"cannot be read ({e.strerror})"
    if stat.S_ISDIR(st.st_mode):
        return None if folder_ok else "is a folder, not a file"
    if stat.S_ISREG(st.st_mode):
        return None
    kind = next((k for test, k in _KINDS if test(st.st_mode)), "a special file")
    return f"is {kind}, not a regular file"
