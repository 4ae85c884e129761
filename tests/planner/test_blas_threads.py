"""BLAS threads are capped while a request runs and restored afterwards (planner/blas_threads.py)."""
import numpy as np
import pytest
import torch

threadpoolctl = pytest.importorskip("threadpoolctl")

from cinenerf_ns.planner import blas_threads as bt  # noqa: E402
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene  # noqa: E402
from cinenerf_ns.planner.scene.procedural import procedural_room  # noqa: E402
from cinenerf_ns.planner.shots import stages  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402

THREADED: set = set()  # the BLAS libraries (paths) that run on 2 threads in the fixture; others are built for one


def blas_counts() -> set:
    """The thread counts of the loaded BLAS libraries that can run threaded (THREADED)."""
    return {lib["num_threads"] for lib in threadpoolctl.threadpool_info()
            if lib["user_api"] == "blas" and lib["filepath"] in THREADED}


@pytest.fixture
def two_blas_threads(monkeypatch):
    # a fresh controller: the module keeps the one built on first use, and in a test process that can be before
    # another test imports cvxpy (the tests' reference), which loads scs's own OpenBLAS; the cap then missed it and
    # these tests failed when tests/planner ran alone under xdist. The planner itself loads no BLAS after import.
    monkeypatch.setattr(bt, "_controller", None)
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        THREADED.clear()
        THREADED.update(lib["filepath"] for lib in threadpoolctl.threadpool_info()
                        if lib["user_api"] == "blas" and lib["num_threads"] == 2)
        if not THREADED:
            pytest.skip("numpy / scipy loaded no threaded BLAS that threadpoolctl sees")
        yield


def test_the_block_caps_and_restores(two_blas_threads):
    with bt.blas_threads(1):
        assert blas_counts() == {1}
    assert blas_counts() == {2}
    with bt.blas_threads(None):  # None: untouched
        assert blas_counts() == {2}


def test_a_request_runs_with_one_blas_thread(two_blas_threads, monkeypatch):
    s = procedural_room(3000, seed=1)
    scene = EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits)
    planner = Planner(scene, PlannerConfig(grid_resolution=48))
    seen = []
    solve = stages.solve_corridor_qp

    def spy(*a, **k):  # the QP: the request's BLAS work
        seen.append(blas_counts())
        return solve(*a, **k)

    monkeypatch.setattr(stages, "solve_corridor_qp", spy)
    lo, hi = planner.region()
    shot = planner.plan(goal=0.7 * lo + 0.3 * hi, look_at=0.5 * (lo + hi), seed=0)[0]
    assert shot.safety["safe"]
    assert seen and all(s == {1} for s in seen)
    assert blas_counts() == {2}  # restored after the request
    assert torch.get_num_threads() >= 1


def test_set_blas_threads_holds_for_the_process(two_blas_threads):
    bt.set_blas_threads(1)
    assert blas_counts() == {1}
    np.linalg.cholesky(np.eye(4))  # still usable
