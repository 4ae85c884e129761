"""BLAS threads capped while a request runs.

Why: a request's linear algebra is small (Gram matrices and Cholesky factors of a few hundred rows), and OpenBLAS
threads it anyway. Its worker threads then wait for cores that torch's threads, the viewer or other processes hold
(docs/PLANNER_DEFAULTS.md, plan_cpu_threads). threadpoolctl (a scikit-learn dependency, listed in ours) sets the limit
of the BLAS libraries numpy and scipy loaded; without it the cap is skipped and nothing else changes.
"""
from __future__ import annotations

import contextlib
from typing import Optional

_controller = None  # threadpoolctl.ThreadpoolController, built on first use (it inspects the loaded libraries)


def _blas_controller():
    global _controller
    if _controller is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency; a bare environment keeps BLAS as is
            _controller = False
        else:
            _controller = ThreadpoolController()
    return _controller or None


def warm_blas_controller() -> None:
    """Build the controller now (Planner.prepare), not in the first request: threadpoolctl inspects every loaded
    library, ~10 ms the first request otherwise paid outside its own stage timings."""
    _blas_controller()


def _blas_libraries(ctl) -> Optional[list]:
    """threadpoolctl's controllers of the BLAS libraries ``ctl`` found (kept on it: they are the same objects for its
    lifetime), or None when this threadpoolctl does not offer them (blas_threads then uses its ``limit``)."""
    libs = getattr(ctl, "_cinenerf_blas", None)
    if libs is None:
        try:
            libs = list(ctl.select(user_api="blas").lib_controllers)
            for lc in libs:  # the calls blas_threads makes
                lc.num_threads  # noqa: B018
                lc.set_num_threads  # noqa: B018
        except AttributeError:  # pragma: no cover - an older or newer threadpoolctl
            libs = False
        ctl._cinenerf_blas = libs
    return None if libs is False else libs


@contextlib.contextmanager
def blas_threads(limit: Optional[int]):
    """Cap numpy's / scipy's BLAS at ``limit`` threads inside the block (None: untouched); restored afterwards.
    Each library's thread count is read and, where it differs, set and restored directly: threadpoolctl's ``limit``
    inspects every library again on entry and exit (~60 us a request on the CPU box, 1% of a 1M grove request)."""
    ctl = _blas_controller() if limit is not None else None
    if ctl is None:
        yield
        return
    libs = _blas_libraries(ctl)
    if libs is None:  # pragma: no cover - see _blas_libraries
        with ctl.limit(limits=int(limit), user_api="blas"):
            yield
        return
    n = int(limit)
    changed = []
    try:
        for lc in libs:
            old = lc.num_threads
            if old != n:
                lc.set_num_threads(n)
                changed.append((lc, old))
        yield
    finally:
        for lc, old in changed:
            lc.set_num_threads(old)


def set_blas_threads(limit: int) -> None:
    """Cap numpy's / scipy's BLAS at ``limit`` threads for the rest of the process (a candidate worker: one process
    per core, so threads inside a worker only compete with the other workers)."""
    ctl = _blas_controller()
    if ctl is not None:
        ctl.limit(limits=int(limit), user_api="blas")  # applied on creation; never restored


@contextlib.contextmanager
def request_threads(threads: Optional[int], on_cpu: bool):
    """torch CPU threads = ``threads`` while a request runs (restored afterwards; only when its queries run on the
    CPU, ``on_cpu``): a plan is many small ops, for which extra threads cost more than they give. numpy's / scipy's
    BLAS threads are capped the same way (blas_threads), on any device: the QP's linear algebra always runs on the
    CPU. None: both untouched."""
    import torch

    old = torch.get_num_threads()
    swap = threads is not None and on_cpu and int(threads) != old
    if swap:
        torch.set_num_threads(int(threads))
    try:
        with blas_threads(threads):
            yield
    finally:
        if swap:
            torch.set_num_threads(old)
