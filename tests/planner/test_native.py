"""cinenerf_ns/planner/native: the compiled A* / Dijkstra (astar26.c) against the pure-Python A*, scipy's
Dijkstra and scikit-image's MCP, and the fallback when no compiled kernel can be had."""
from __future__ import annotations

import contextlib
import io
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from test_astar import check_path, random_case

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import GoalUnreachableError
from cinenerf_ns.planner.search import coarse_path
from cinenerf_ns.planner.search.astar import AStarGrid, SearchBudgetExhausted, astar, path_cost

SETTINGS = dict(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

needs_native = pytest.mark.skipif(native.astar26() is None, reason=f"no compiled A*: {native.native_status()}")


@needs_native
@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(1, 10), st.integers(1, 10), st.integers(1, 9)),
       density=st.floats(0.0, 0.6), weight=st.sampled_from([1.0, 1.5, 3.0]))
def test_native_astar_is_the_python_astar(seed, shape, density, weight):
    """Same search, same tie-breaking: the very same path (and Dijkstra's cost at weight 1)."""
    case = random_case(seed, shape, density)
    if case is None:
        return
    occ, s, g, ref = case
    G = AStarGrid(occ)
    for check in (True, False):
        if not np.isfinite(ref):
            for backend in ("native", "python"):
                with pytest.raises(GoalUnreachableError):
                    astar(G, s, g, backend=backend, check_components=check, heuristic_weight=weight)
            continue
        pn = astar(G, s, g, backend="native", check_components=check, heuristic_weight=weight)
        pp = astar(G, s, g, backend="python", check_components=check, heuristic_weight=weight)
        check_path(pn, occ, s, g)
        assert np.array_equal(pn, pp)
        assert ref - 1e-9 <= path_cost(pn) <= weight * ref + 1e-9


@needs_native
def test_native_budget_is_the_python_budget():
    occ = np.zeros((20, 20, 20), bool)
    occ[10, :, :15] = True
    for budget in (0, 5, 50, 400, 3000):
        outcomes = []
        for backend in ("native", "python"):
            try:
                outcomes.append(astar(occ, (0, 0, 0), (19, 0, 0), max_expansions=budget, backend=backend).tolist())
            except SearchBudgetExhausted:
                outcomes.append("budget")
        assert outcomes[0] == outcomes[1]
    assert len(astar(occ, (0, 0, 0), (19, 0, 0), max_expansions=10_000, backend="native")) > 0


@needs_native
def test_kept_workspace_gives_the_fresh_search_every_time():
    """Large grids search with a workspace kept between calls (astar26.c: search26_ws); stamps left by earlier
    searches (found, exhausted, Dijkstra to a set) must not change any later one: the same path as a fresh grid's
    Python A*, also across the generation wrap-around."""
    from cinenerf_ns.planner.search.astar import WORKSPACE_MIN_VOXELS
    from cinenerf_ns.planner.search.coarse_path import _mcp_path

    rng = np.random.default_rng(3)
    occ = rng.random((34, 33, 30)) < 0.3
    G = AStarGrid(occ)
    assert G._blocked_np.size >= WORKSPACE_MIN_VOXELS  # the kept-workspace path is the one under test
    lab = G.labels
    free = np.argwhere(~occ)
    for it in range(40):
        s, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
        if it == 20:  # this search uses the last generation; the next ones start over from cleared stamps
            G._local.ws.gen = 2**31 - 2
            same = free[lab[tuple(free.T)] == lab[tuple(s)]]
            g = same[np.argmax(np.abs(same - s).sum(1))]  # a long search that is sure to run
        budget = [None, 30][it % 2] if it != 20 else None
        outcomes = []
        for grid, backend in ((G, "native"), (AStarGrid(occ), "python")):
            try:
                outcomes.append(astar(grid, s, g, max_expansions=budget, backend=backend).tolist())
            except SearchBudgetExhausted:
                outcomes.append("budget")
            except GoalUnreachableError:
                outcomes.append("unreachable")
        assert outcomes[0] == outcomes[1], it
        if it == 20:
            assert G._local.ws.gen == 1 and not G._local.ws.stamp.any()
        ends = free[rng.integers(len(free), size=3)]
        ends = ends[lab[tuple(ends.T)] == lab[tuple(s)]]
        if len(ends):  # Dijkstra to the nearest end: a minimum-cost path, as without a kept workspace
            p = _mcp_path(np.where(occ, np.inf, 1.0), s, ends, grid=G)
            check_path(p, occ, s, p[-1])
            assert any((p[-1] == e).all() for e in ends)
            best = min(path_cost(astar(AStarGrid(occ), s, e, backend="python")) for e in ends)
            assert path_cost(p) == pytest.approx(best, abs=1e-9)


@needs_native
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), density=st.floats(0.0, 0.45), weight=st.sampled_from([1.0, 1.5]),
       budgets=st.lists(st.sampled_from([0, 1, 3, 30, 200, -1]), min_size=1, max_size=4),
       heap_items=st.sampled_from([1, 8, 64, 32_768]), other=st.booleans())
def test_resumed_search_is_the_fresh_search(monkeypatch, seed, density, weight, budgets, heap_items, other):
    """search26_wsr: an A* its budget stopped goes on in the next call of the same search from where it stopped (the
    open list kept in the workspace's buffer, ``heap_items`` of them: a larger list is copied back when it fits, else
    not kept), expansions counted from the first call; so every call answers what a fresh search with that call's
    budget answers (the Python A*), also when another search (``other``) runs in between and drops the kept one."""
    from cinenerf_ns.planner.search import astar as astar_mod

    monkeypatch.setattr(astar_mod, "RESUME_HEAP_ITEMS", heap_items)
    rng = np.random.default_rng(seed)
    occ = rng.random((34, 33, 30)) < density
    G = AStarGrid(occ)
    assert G._blocked_np.size >= astar_mod.WORKSPACE_MIN_VOXELS
    free = np.argwhere(~occ)
    if len(free) < 2:
        return
    s, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
    resumed = 0
    for budget in sorted(budgets, key=lambda b: b if b >= 0 else 1 << 40):
        ws = getattr(G._local, "ws", None)
        resumed += ws is not None and ws.pending is not None
        outcomes = []
        for grid, backend in ((G, "native"), (AStarGrid(occ), "python")):
            try:
                outcomes.append(astar(grid, s, g, max_expansions=None if budget < 0 else budget, backend=backend,
                                      heuristic_weight=weight).tolist())
            except SearchBudgetExhausted:
                outcomes.append("budget")
            except GoalUnreachableError:
                outcomes.append("unreachable")
        assert outcomes[0] == outcomes[1], budget
        if other:  # an unrelated search drops the kept one: the next call starts afresh
            t = free[rng.integers(len(free))]
            try:
                astar(G, t, s, max_expansions=5, backend="native")
            except GoalUnreachableError:
                pass
    assert resumed <= len(budgets)


@needs_native
def test_budget_then_unbounded_resumes():
    """The case coarse_path.voxel_path relies on: a fine A* stopped by its budget, then the same search unbounded,
    resumes (the kept open list is used) and returns the fresh search's path."""
    from cinenerf_ns.planner.search.astar import WORKSPACE_MIN_VOXELS

    occ = np.zeros((40, 40, 30), bool)
    occ[20, :, :25] = True  # a wall: the straight line fails, the search floods
    G = AStarGrid(occ)
    assert G._blocked_np.size >= WORKSPACE_MIN_VOXELS
    with pytest.raises(SearchBudgetExhausted):
        astar(G, (0, 5, 0), (39, 5, 0), max_expansions=100, backend="native")
    ws = G._local.ws
    assert ws.pending is not None and ws.state[0] > 0 and ws.state[1] == 100
    gen = ws.gen
    p = astar(G, (0, 5, 0), (39, 5, 0), backend="native")
    assert ws.pending is None and ws.gen == gen + 1  # resumed with the kept generation, then advanced
    assert np.array_equal(p, astar(occ, (0, 5, 0), (39, 5, 0), backend="python"))
    fine = np.where(occ, np.inf, 1.0)
    with pytest.raises(SearchBudgetExhausted):
        astar(G, (0, 5, 0), (39, 5, 0), max_expansions=100, backend="native")
    q = coarse_path._mcp_path(fine, np.array([0, 5, 0]), np.array([[39, 5, 0]]), grid=G)  # voxel_path's fallback
    assert np.array_equal(q, p)


@needs_native
def test_native_long_path_on_a_big_grid():
    """A whole-grid search (a wall with one hole in the far corner) on the planner's grid size."""
    occ = np.zeros((96, 96, 57), bool)
    occ[48] = True
    occ[48, 95, 56] = False
    p = astar(occ, (0, 0, 0), (95, 0, 0), backend="native")
    check_path(p, occ, (0, 0, 0), (95, 0, 0))
    assert [48, 95, 56] in p.tolist()
    assert path_cost(p) == pytest.approx(path_cost(astar(occ, (0, 0, 0), (95, 0, 0), backend="python")), abs=1e-9)


@needs_native
@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 8)),
       density=st.floats(0.0, 0.6), n_ends=st.integers(1, 6))
def test_nearest_end_path_matches_mcp(seed, shape, density, n_ends):
    """coarse_path._mcp_path through the compiled Dijkstra: a valid 26-connected path through finite costs to
    one of the ends, of the same cost as scikit-image's MCP (the tie between equal paths may differ)."""
    from skimage.graph import MCP_Geometric

    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < density
    free = np.argwhere(~occ)
    if len(free) == 0:
        return
    s = free[rng.integers(len(free))]
    ends = free[rng.integers(len(free), size=n_ends)]
    costs = np.where(occ, np.inf, 1.0)
    p = coarse_path._mcp_path(costs, s, ends)
    mcp = MCP_Geometric(costs, fully_connected=True)
    cum, _ = mcp.find_costs([tuple(s)], [tuple(e) for e in ends], find_all_ends=False)
    ref = cum[tuple(ends.T)].min()
    if not np.isfinite(ref):
        assert p is None
        return
    assert p is not None and tuple(p[0]) == tuple(s)
    assert any(tuple(p[-1]) == tuple(e) for e in ends)
    assert not occ[tuple(p.T)].any()
    assert (np.abs(np.diff(p, axis=0)).max(1) == 1).all() if len(p) > 1 else True
    assert path_cost(p) == pytest.approx(ref, abs=1e-9)


def _run(code: str, **env) -> str:
    import os

    e = {**os.environ, **env}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=e, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


PROBE = (
    "import numpy as np\n"
    "from cinenerf_ns.planner import native\n"
    "from cinenerf_ns.planner.search.astar import astar\n"
    "from cinenerf_ns.planner.search.coarse_path import _mcp_path\n"
    "occ = np.zeros((6, 6, 6), bool); occ[3, :, :5] = True\n"
    "print(len(astar(occ, (0, 0, 0), (5, 0, 0))), "
    "len(_mcp_path(np.where(occ, np.inf, 1.0), (0, 0, 0), np.array([[5, 0, 0]]))))\n"
    "print(native.astar26() is None, native.native_status().get('astar26'))\n"
)


def test_turned_off_falls_back_to_python(tmp_path):
    out = _run(PROBE, CINENERF_NATIVE="0", CINENERF_CACHE=str(tmp_path)).splitlines()
    assert out[1] == "True turned off (CINENERF_NATIVE=0)"
    assert out[0] == "11 11"  # 5 moves up to the gap at (3, y, 5) (5 z-steps), 5 down to (5, 0, 0): 11 voxels
    assert not any(tmp_path.iterdir())  # nothing was compiled


POLY_PROBE = (
    "import numpy as np, torch\n"
    "from cinenerf_ns.planner import native\n"
    "from cinenerf_ns.planner.corridor.polytope import safe_polytope\n"
    "from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene\n"
    "from cinenerf_ns.planner.scene.spatial_index import GridIndex\n"
    "s = EllipsoidScene(torch.tensor([[0.3, 0, 0]]).double(), torch.eye(3)[None].double(), "
    "torch.full((1, 3), 0.1).double(),\n"
    "                   torch.ones(1).double(), 0.03)\n"
    "P = safe_polytope(np.zeros((1, 3)), s, GridIndex.build(s), -np.ones(3), np.ones(3))\n"
    "print(P.num_faces, round(float(P.b[6]), 6))\n"
    "print(native.safe_polytope_c() is None, native.native_status().get('polytope'))\n"
    "print(native.astar26() is None)\n"
)


def test_one_library_turned_off_falls_back_to_python(tmp_path):
    """CINENERF_NATIVE_OFF=polytope: the polytope takes the Python path (same plane here), A* stays compiled."""
    out = _run(POLY_PROBE, CINENERF_NATIVE_OFF="polytope", CINENERF_CACHE=str(tmp_path)).splitlines()
    assert out[0] == "7 0.169999"  # one plane x <= 0.3 - 0.1 - 0.03 - 1e-6 (margin)
    assert out[1] == "True turned off (CINENERF_NATIVE_OFF)"
    if native.astar26() is not None:
        assert out[2] == "False"
        # without the switch (this process: no CINENERF_NATIVE_OFF, its libraries already loaded) the same probe takes
        # the compiled polytope and gives the same plane
        on = io.StringIO()
        with contextlib.redirect_stdout(on):
            exec(POLY_PROBE, {})
        on = on.getvalue().splitlines()
        assert on[0] == out[0] and on[1].startswith("False compiled: ")


def test_broken_compiler_falls_back_to_python(tmp_path):
    out = _run(PROBE, CC="/bin/false", CINENERF_CACHE=str(tmp_path)).splitlines()
    assert out[1].startswith("True compiling astar26.c failed")
    assert out[0] == "11 11"


@needs_native
def test_compiles_into_the_cache_once(tmp_path):
    out = _run(PROBE, CINENERF_CACHE=str(tmp_path)).splitlines()
    assert out[0] == "11 11" and out[1].startswith("False compiled: ")
    libs = sorted(p.name for p in tmp_path.iterdir())
    assert len(libs) == 1 and libs[0].startswith("astar26-") and libs[0].endswith(".so")
    mtime = next(tmp_path.iterdir()).stat().st_mtime_ns
    _run(PROBE, CINENERF_CACHE=str(tmp_path))  # a second process loads the cached library
    assert next(tmp_path.iterdir()).stat().st_mtime_ns == mtime


def test_backend_errors():
    occ = np.zeros((4, 4, 4), bool)
    with pytest.raises(Exception, match="backend"):
        astar(occ, (0, 0, 0), (3, 3, 3), backend="fast")


@settings(max_examples=200, deadline=None)
@given(lb=st.lists(st.sampled_from([-0.8, 0.0, 0.25, 1.0, 1.5, 3.0]) | st.floats(-1.0, 50.0), max_size=200),
       depth=st.sampled_from([0, 1, 3, 64]), pattern=st.sampled_from(["as drawn", "sorted", "reversed", "equal"]))
def test_native_cube_sort_is_lexsort(lb, depth, pattern):
    """gridpoly.c's cube sort (quicksort, insertion sort for small runs, qsort past the depth limit): the order of
    numpy's lexsort by (lower bound, then index), which the Python grid polytope visits (a stable argsort)."""
    fn = native.sort_cubes_c()
    if fn is None:
        pytest.skip("the compiled grid polytope does not load here")
    x = np.asarray(lb, dtype=np.float64)
    x = {"sorted": np.sort(x), "reversed": np.sort(x)[::-1].copy(), "equal": np.zeros_like(x)}.get(pattern, x)
    out = np.empty(len(x), dtype=np.int64)
    assert fn(x.ctypes.data, len(x), depth, out.ctypes.data) == 0
    assert np.array_equal(out, np.lexsort((np.arange(len(x)), x)))


PLAN_PROBE = (
    "import warnings\n"
    "warnings.simplefilter('ignore')\n"
    "from cinenerf_ns.planner import native\n"
    "from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene\n"
    "from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig\n"
    "from cinenerf_ns.synthetic.blobs import blob_scene\n"
    "b = blob_scene(20000, seed=0)\n"
    "scene = EllipsoidScene.from_params(b.splat, device='cpu')\n"
    "r = float(scene.camera_radius)\n"
    "pl = Planner(scene, PlannerConfig(up=b.up, start_region=(b.free_lo + r, b.free_hi - r), grid_resolution=48))\n"
    "shots = [pl.plan(b.blobs[k].center, b.blobs[k + 1].center, seed=k)[0] for k in range(3)]\n"
    "print(sum(bool(s.safety['safe']) and len(s.positions) > 1 for s in shots))\n"
    "print(sorted(set(native.native_status().values())))\n"
)


def test_a_whole_plan_without_compiled_kernels(tmp_path):
    """CINENERF_NATIVE=0 (a user without a C compiler): every stage of a plan takes its Python path (A*, the grid
    and Prop-2 polytopes, the corner detours' voxel walk, the QP, the goal windows, timing, rotations), and the shots
    come back verified safe."""
    out = _run(PLAN_PROBE, CINENERF_NATIVE="0", CINENERF_CACHE=str(tmp_path)).splitlines()
    assert out[0] == "3"
    assert out[1] == "['turned off (CINENERF_NATIVE=0)']"
    assert not any(tmp_path.iterdir())  # nothing was compiled
