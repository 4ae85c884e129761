"""A fork-based process pool that runs per-candidate planning work on a prepared Planner.

Why processes: a request is thousands of small numpy / torch CPU ops in Python, holding the GIL (a thread
pool gave no speed-up). Candidates are independent, so K of them can run in K processes. This is parallelism over
CPU processes, not vectorised batching.

Why fork: the workers must see the prepared planner (CPU scene mirror, spatial index, occupancy grid, A*
grid, free-space labels; hundreds of MB at 1M Gaussians) without pickling it. A forked child shares the
parent's memory copy-on-write, so the only per-worker memory is the pages a worker writes (Python's reference
counts touch object headers, not the big tensor / array buffers). Only the 'fork' start method can do this:
on platforms without it (macOS defaults to spawn, Windows has no fork) ``default_workers`` returns 0 and
requests run in the calling process.

Rules for the work sent here (see candidates._plan_candidate_task):
  - CPU tensors only. CUDA cannot be used in a forked child: nothing with ``batch=True``, no ``batch_scene``,
    no ``batch_index``. The pool is refused (``usable``) when the request device is not the CPU.
  - one thread per worker (initializer): more would oversubscribe the cores, and OpenMP thread pools started
    before the fork are not valid in the child.
Tasks and results are pickled with the standard pickler (``pickle.dumps``: bytes cross the process boundary),
not multiprocessing's ForkingPickler: torch registers reducers there that move CPU tensors into shared memory and
send file descriptors, which is slower for small tensors (a task's goal carries its polytope's tensors) and can
run out of descriptors.

A concurrent.futures ProcessPoolExecutor rather than multiprocessing.Pool: when a worker dies (killed, out of
memory) it raises BrokenProcessPool instead of waiting forever for the lost task; plan_candidates then
closes the pool and plans the request in this process.
"""
from __future__ import annotations

import multiprocessing as mp
import pickle
import signal
import weakref
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterable, Iterator, List, Optional

import torch

from ..blas_threads import set_blas_threads
from ..config import validate_workers
from ..errors import InvalidInputError
from ..host_pool import fork_available, in_worker, mark_worker, usable_cpus
from ..native import set_kernel_threads

# the planner a worker serves; set in the child by _init_worker (inherited through fork, never pickled)
_PLANNER: Any = None


def default_workers() -> int:
    """Worker processes for PlannerConfig.candidate_workers=None: one per usable CPU (the parent only waits while
    they plan: 32 candidates on a 16-CPU host are then two rounds, not three with 15 workers), when fork exists
    and there are at least 4 CPUs; else 0."""
    n = usable_cpus()
    return n if fork_available() and n >= 4 else 0


def candidate_workers(planner: Any) -> int:
    """Worker processes plan_candidates uses now: the planner's config.candidate_workers resolved (None: auto,
    default_workers), 0 when requests run on a non-CPU device (a forked child cannot use CUDA)."""
    n = planner.config.candidate_workers
    validate_workers(n)
    n = default_workers() if n is None else int(n)
    if n:
        planner.ready()  # the request device (planner.scene's) is settled by prepare()
        if planner.scene.device.type != "cpu":
            return 0
    return n


def _preload() -> None:
    """Load, before the fork, what candidate tasks would otherwise load lazily in every worker on first use: each
    child would import on its own, and a round waits for its slowest candidate (a first use, e.g. scipy.optimize's
    HiGHS LP of an overlap check, costs a corridor many times its usual time: docs/PLANNER_DEFAULTS.md)."""
    import numpy as np
    import scipy.linalg  # noqa: F401 - the QP's equality projection
    import scipy.sparse  # noqa: F401
    from scipy.optimize import linprog

    try:
        import clarabel  # noqa: F401 - the corridor QP
    except ImportError:
        pass
    # a tiny LP: HiGHS's own first-call set-up happens here too
    linprog(np.array([0.0, -1.0]), A_ub=np.array([[1.0, 1.0]]), b_ub=np.array([1.0]), bounds=[(None, None), (0.0, 1.0)],
            method="highs")


def _init_worker(planner_ref: "weakref.ref") -> None:
    global _PLANNER
    for s in (signal.SIGTERM, signal.SIGHUP):  # the parent's handlers (the CLI's clean-up) are not the worker's
        signal.signal(s, signal.SIG_DFL)
    torch.set_num_threads(1)
    set_blas_threads(1)
    set_kernel_threads(1)  # the compiled kernels too: the other workers use the other CPUs
    _PLANNER = planner_ref()
    mark_worker()


def _task(fn: Callable, args: tuple) -> bytes:
    """A task as bytes (standard pickler, see the module docstring), for _call in a worker."""
    return pickle.dumps((fn, tuple(args)), protocol=pickle.HIGHEST_PROTOCOL)


def _call(task: bytes) -> bytes:
    fn, args = pickle.loads(task)
    return pickle.dumps(fn(_PLANNER, *args), protocol=pickle.HIGHEST_PROTOCOL)


__all__ = ["BrokenProcessPool", "CandidatePool", "candidate_workers", "default_workers", "fork_available", "in_worker",
           "pool_for", "usable_cpus", "validate_workers"]


class CandidatePool:
    """``processes`` forked workers serving ``planner`` (as it is at the fork: the caller recreates the pool
    after planner.prepare() runs again). ``map(fn, args_list)`` runs fn(planner, *args) in the workers and
    returns the results in order; fn must be a module-level function (pickled by name)."""

    def __init__(self, planner: Any, processes: int):
        if processes < 1:
            raise InvalidInputError(f"a candidate pool needs >= 1 process, got {processes}")
        self.processes = int(processes)
        _preload()  # inherited by every worker (fork)
        # a weak reference in initargs: with fork it is inherited, not pickled, and the executor (which keeps
        # initargs) then does not keep the planner alive
        self._pool = ProcessPoolExecutor(self.processes, mp_context=mp.get_context("fork"), initializer=_init_worker,
                                         initargs=(weakref.ref(planner),))
        # with fork all workers start at the first submit: fork them now, while the planner is as prepared
        self._pool.submit(int).result()
        # no process left behind: on planner garbage collection or interpreter exit (finalize's atexit)
        self._finalizer = weakref.finalize(planner, CandidatePool._terminate, self._pool)

    @staticmethod
    def _terminate(pool: ProcessPoolExecutor) -> None:
        # between requests no task runs (map waits for all); joins the workers
        pool.shutdown(wait=True, cancel_futures=True)

    def map(self, fn: Callable, args_list: Iterable[tuple]) -> List[Any]:
        """fn(planner, *args) for each args in the workers, results in order. Raises BrokenProcessPool when a
        worker died, and whatever fn raised."""
        blobs = self._pool.map(_call, [_task(fn, a) for a in args_list], chunksize=1)
        return [pickle.loads(b) for b in blobs]

    def imap_unordered(self, fn: Callable, args_list: Iterable[tuple]) -> Iterator[tuple]:
        """(i, fn(planner, *args_list[i])) for each task, in the order they finish (the caller can use early results
        while the others run). Raises BrokenProcessPool when a worker died, and whatever fn raised."""
        futures = {self._pool.submit(_call, _task(fn, a)): i for i, a in enumerate(args_list)}
        for f in as_completed(futures):
            yield futures[f], pickle.loads(f.result())

    @property
    def closed(self) -> bool:
        """The workers were terminated (close(), or the planner was collected)."""
        return not self._finalizer.alive

    def close(self) -> None:
        """Terminate and join the workers (idempotent)."""
        self._finalizer()


def pool_for(planner: Any, prepared: Any, processes: int, current: Optional[tuple]) -> tuple:
    """(prepared, processes, CandidatePool): ``current`` when it was made for this PreparedScene object and
    size, else a new pool (the old one closed) forked from the planner as it is now."""
    if current is not None:
        prep, n, pool = current
        if prep is prepared and n == processes and not pool.closed:
            return current
        pool.close()
    return (prepared, processes, CandidatePool(planner, processes))
