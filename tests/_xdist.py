"""The suite under pytest-xdist (`make test`: -n auto --dist loadgroup): ports that no two tests of a run share, and the
one group of tests that runs on one worker.

Ports: a port the OS hands out for port 0 is free when asked for, but a test binds it only later (a viser server, a
subprocess viewer); two workers given the same port would race for it. Under xdist every port handed out is recorded in
the run's shared folder (RUN_DIR: the parent of the workers' pytest basetemps, set by tests/conftest.py) with an
exclusive create, and a port another worker holds is not handed out again: tests that open ports run on any worker.

Groups: the headless-Chromium tests (test_browser.py) run on one worker, one after another: two software-rendering
browsers at once starve a 2-core box (a page once took over 60 s to show its panel). xdist's own `xdist_group` mark does
nothing with pytest 9.2 (pytest-xdist 3.8 renames node ids through a field pytest 9.2 no longer reads:
pytest-dev/pytest-xdist#1386), so the scheduler groups by file (make_scheduler, used by tests/conftest.py). xdist hands
out the largest group first, so the browser tests start at once while the other worker takes the rest."""
from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import Any, Optional

RUN_DIR: Optional[Path] = None  # set under xdist by tests/conftest.py (the run's folder of ports handed out)

# test file (relative to the repository) -> its xdist group. "ns-train": that file's tests share one Python process (a
# module-scoped fixture), which runs once only when they run on one worker.
GROUPS = {"tests/viewer/test_browser.py": "browser", "tests/method/test_ns_train_cli.py": "ns-train"}


def reserve(port: int, run_dir: Optional[Path] = None) -> bool:
    """Record ``port`` as given to a test of this run; False when another test of the run already has it."""
    d = RUN_DIR if run_dir is None else run_dir
    if d is None:
        return True
    d.mkdir(parents=True, exist_ok=True)
    try:
        os.close(os.open(d / str(port), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def free_port(run_dir: Optional[Path] = None) -> int:
    """A free port on 127.0.0.1 that no other test of this run has been given."""
    for _ in range(200):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if reserve(port, run_dir):
            return port
    raise RuntimeError("no free port that this test run has not handed out already")


def group_of(nodeid: str) -> Optional[str]:
    """The xdist group of a test (None: scheduled on its own)."""
    return GROUPS.get(nodeid.split("::", 1)[0])


def scheduler_class() -> type:
    """xdist's loadgroup scheduler with the groups of GROUPS: every other test is its own unit of work."""
    from xdist.scheduler import LoadGroupScheduling

    class FileGroupScheduling(LoadGroupScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return group_of(nodeid) or super()._split_scope(nodeid)

    return FileGroupScheduling


def make_scheduler(config: Any, log: Any = None) -> Any:
    return scheduler_class()(config, log)
