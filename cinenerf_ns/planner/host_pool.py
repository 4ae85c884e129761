"""A shared thread pool for independent pieces of a request whose time is spent in compiled kernels.

Why threads here, when candidates use processes (shots/workers.py): a corridor's polytopes are independent, and
almost all of each one's time is one ctypes call into native/polytope.c or native/gridpoly.c, which releases the
GIL. Several of them then run at once on several cores, while Python-heavy work (most of a request) would not
(the GIL). The kernels keep no global state: every call reads its inputs and writes its own outputs.

The pool is created on first use, sized on demand, and never crosses a fork: a forked child (a candidate worker)
that asks for threads gets a new pool of its own, since the parent's threads do not exist there. ``threads`` 1 (or
one item) runs in the calling thread: the same calls, in the same order.
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, List, Optional, Sequence, TypeVar

T = TypeVar("T")
R = TypeVar("R")

_IN_WORKER = False  # set in a forked candidate worker (shots/workers.py), which must not use CUDA


def mark_worker() -> None:
    """Record that this process is a forked candidate worker (its initializer calls this)."""
    global _IN_WORKER
    _IN_WORKER = True


def in_worker() -> bool:
    """True inside a candidate worker process (forked: no CUDA there)."""
    return _IN_WORKER


def fork_available() -> bool:
    """The 'fork' start method exists here (Linux): the only one whose workers see the prepared planner unpickled."""
    import multiprocessing as mp

    return "fork" in mp.get_all_start_methods()


def usable_cpus() -> int:
    """CPUs this process may run on (the affinity mask in a container / taskset), else os.cpu_count()."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


_LOCK = threading.Lock()
_POOL: Optional[ThreadPoolExecutor] = None
_POOL_PID = -1
_POOL_SIZE = 0


def _pool(threads: int) -> ThreadPoolExecutor:
    """The process's pool with at least ``threads`` threads (a new one after a fork or when more are asked for)."""
    global _POOL, _POOL_PID, _POOL_SIZE
    with _LOCK:
        if _POOL is None or _POOL_PID != os.getpid() or _POOL_SIZE < threads:
            old = _POOL if _POOL_PID == os.getpid() else None
            _POOL = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="cinenerf-host")
            _POOL_PID, _POOL_SIZE = os.getpid(), threads
            if old is not None:
                old.shutdown(wait=False)
        return _POOL


def ordered_map(fn: Callable[[T], R], items: Sequence[T], threads: int = 1) -> List[R]:
    """[fn(x) for x in items], with up to ``threads`` of the calls running at once (threads <= 1 or fewer than two
    items: in this thread, in order). Results come back in the items' order. If calls raise, the exception of the
    first failing item (in the items' order) is raised, after every call has finished, as the serial loop would
    raise it (later items may have run, which only costs their time: the calls must be free of side effects that
    matter)."""
    items = list(items)
    if threads <= 1 or len(items) < 2:
        return [fn(x) for x in items]
    futures = [_pool(int(threads)).submit(fn, x) for x in items]
    out: List[R] = []
    err: Optional[BaseException] = None
    for f in futures:
        try:
            r = f.result()
        except BaseException as e:  # noqa: BLE001 - re-raised below, in order
            err = e if err is None else err
            r = None
        out.append(r)
    if err is not None:
        raise err
    return out
