"""All-or-nothing outputs: a run writes its files into a hidden folder beside their destination and moves the complete
set into place at the end; an interrupted or failed run leaves the folder as it was. Files of an earlier run under
the same name that this run does not rewrite are removed (a report never sits beside another run's camera paths)."""
from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import signal
import tempfile
from pathlib import Path
from typing import Iterator, List, Optional

from cinenerf_ns.planner.atomic import FILE_MODE
from cinenerf_ns.planner.errors import InvalidInputError

NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


def check_name(name: str, option: str = "--name") -> str:
    """A file-name stem: letters, digits, '.', '_', '-' (1-100 characters, no folder)."""
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise InvalidInputError(f"{option} must be 1-100 letters, digits, '.', '_' or '-' (no folder), got {name!r}")
    return name


def check_writable(folder: Path, option: str = "--output-dir") -> Path:
    """InvalidInputError unless ``folder`` is (or can be created as) a writable folder; creates nothing (a probe file
    is made and removed in the nearest existing folder)."""
    folder = Path(folder).expanduser().absolute()
    probe: Optional[Path] = folder
    while probe is not None and not probe.exists():
        probe = probe.parent if probe.parent != probe else None
    if probe is None or not probe.is_dir():
        what = "is a file" if probe is not None and probe == folder else f"lies under {probe}, which is not a folder"
        raise InvalidInputError(f"{option} {folder} {what}; give a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise InvalidInputError(f"{option} {folder}: {probe} is not writable")
    try:  # what access() cannot tell: /proc, a read-only mount, root on a folder that takes no files
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as e:
        raise InvalidInputError(f"{option} {folder}: cannot write into {probe} ({e.strerror})") from None
    return folder


MIN_FILE_SIZE_LIMIT = 64 << 20  # bytes a process must be allowed to write into one file (outputs, previews)


def check_file_size_limit(folder: Path, option: str = "--output-dir", need: int = MIN_FILE_SIZE_LIMIT) -> None:
    """InvalidInputError when the process's file-size limit (ulimit -f) is under ``need`` bytes: the outputs would
    fail at the end of the run, after all the work."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Linux
        return
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if soft != resource.RLIM_INFINITY and soft < need:
        raise InvalidInputError(f"{option} {folder}: the file-size limit (ulimit -f) is {soft} bytes, under the "
                                f"{need >> 20} MiB one output file may need; raise it (ulimit -f unlimited)")


_WRITE_ERRORS = (errno.EFBIG, errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)


class OutputSet:
    """``with OutputSet(folder, name) as out:`` write files to ``out.path(filename)``; they appear in ``folder`` only
    when the block ends without an exception (mode 0644), and earlier files of this name (``name_*``,
    ``name.*``) that the set does not hold are removed then."""

    def __init__(self, folder: Path, name: str, remove_stale: bool = True):
        self.folder = Path(folder).expanduser().absolute()
        self.name = check_name(name)
        self.remove_stale = remove_stale  # False: earlier files of this name are kept unless rewritten
        self.staging: Optional[Path] = None
        self.written: List[Path] = []
        self.created: List[Path] = []

    def __enter__(self) -> "OutputSet":
        missing = [d for d in (self.folder, *self.folder.parents) if not d.exists()]
        self.created = missing[::-1]  # folders this set makes, outermost first: removed again if it fails
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.staging = Path(tempfile.mkdtemp(prefix=f".{self.name}.partial-", dir=self.folder))
        except OSError as e:
            raise InvalidInputError(f"cannot write the outputs into {self.folder}: {e.strerror}") from None
        return self

    def path(self, filename: str) -> Path:
        """Where to write ``filename`` now (inside the staging folder)."""
        assert self.staging is not None, "use OutputSet in a with block"
        return self.staging / filename

    def final(self, filename: str) -> Path:
        """Where ``filename`` will be once the set is complete."""
        return self.folder / filename

    def _ours(self, p: Path) -> bool:
        n = p.name
        return p.is_file() and (n.startswith(self.name + "_") or n.startswith(self.name + "."))

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                with _signals_held():  # a signal now is handled once the set is complete: never half moved
                    self._commit()
        except OSError as e:
            if e.errno not in _WRITE_ERRORS:
                raise
            raise InvalidInputError(f"cannot write the outputs into {self.folder}: {e.strerror}") from None
        finally:
            shutil.rmtree(self.staging, ignore_errors=True)
            if exc_type is not None:  # the folder as it was: no new empty folder either
                for d in reversed(self.created):
                    with contextlib.suppress(OSError):
                        d.rmdir()
        if isinstance(exc, OSError) and exc.errno in _WRITE_ERRORS:  # a write into the staging folder failed
            raise InvalidInputError(f"cannot write the outputs into {self.folder}: {exc.strerror}; nothing was "
                                    f"written") from None

    def _commit(self) -> None:
        new = sorted(self.staging.iterdir())
        for f in new:
            os.chmod(f, FILE_MODE)
        stale = [p for p in self.folder.iterdir() if self.remove_stale and self._ours(p)
                 and not (self.staging / p.name).exists()]
        # the report (name_report.json) last: a reader that sees it sees every file it names
        for f in sorted(new, key=lambda f: f.name.endswith("_report.json")):
            os.replace(f, self.folder / f.name)
            self.written.append(self.folder / f.name)
        for p in stale:
            p.unlink()


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP held (blocked, then delivered) while the block runs."""
    held = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    except (AttributeError, OSError, ValueError):  # pragma: no cover - no POSIX signal masks here
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
