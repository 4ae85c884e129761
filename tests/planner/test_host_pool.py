"""host_pool.ordered_map: the serial loop's results and first error, whatever the thread count, and a fresh pool in a
forked child."""
from __future__ import annotations

import multiprocessing as mp
import threading
import time

import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner import host_pool


@settings(max_examples=30, deadline=None)
@given(items=st.lists(st.integers(-50, 50), max_size=12), threads=st.integers(1, 6))
def test_results_in_order(items, threads):
    def fn(x):
        time.sleep(0.0002 * (x % 3))  # finishing out of order
        return x * x - 1
    assert host_pool.ordered_map(fn, items, threads) == [x * x - 1 for x in items]


@pytest.mark.parametrize("threads", [1, 4])
def test_first_error_in_item_order_after_all_ran(threads):
    ran = []
    lock = threading.Lock()

    def fn(x):
        if x in (2, 5):
            time.sleep(0.02 if x == 2 else 0.0)  # item 5 fails first in time, item 2 first in order
            raise ValueError(f"item {x}")
        with lock:
            ran.append(x)
        return x

    with pytest.raises(ValueError, match="item 2"):
        host_pool.ordered_map(fn, range(8), threads)
    if threads == 1:
        assert sorted(ran) == [0, 1]  # the serial loop stops at the first failure
    else:
        assert sorted(ran) == [0, 1, 3, 4, 6, 7]


def test_calls_run_at_once():
    """With threads, calls that block (as a compiled kernel that releases the GIL does) overlap: a barrier of four
    only opens when all four calls run together."""
    barrier = threading.Barrier(4, timeout=5)
    assert host_pool.ordered_map(lambda x: barrier.wait() >= 0 and x, range(4), 4) == [0, 1, 2, 3]


def _child(q):
    q.put(host_pool.ordered_map(lambda x: x + 1, range(5), 3))


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="needs the fork start method")
def test_forked_child_gets_its_own_pool():
    host_pool.ordered_map(lambda x: x, range(4), 3)  # the parent's pool exists before the fork
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(q,))
    p.start()
    try:
        assert q.get(timeout=10) == [1, 2, 3, 4, 5]  # the parent's threads do not exist there: this would hang
    finally:
        p.join(timeout=20)
        if p.is_alive():
            p.kill()
    assert p.exitcode == 0
