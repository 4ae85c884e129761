"""Issue 35: followed through the code, a request from cinesplat-plan re-enters no module it has left.

One small cinesplat-plan run (run_plan, procedural room of 20k Gaussians, a point go-to) is traced with
sys.setprofile; every Python call made while shot_request.plan_request is on the stack is recorded as the chain of
cinenerf_ns modules from plan_request down to the callee (frames of other packages are transparent).

Definition. A call *re-enters* module M when it goes from a frame of another module N into M while a frame of M is
still on the stack below N: control went down out of M (into N, possibly through others) and comes back into M
before M's frame returned: a call back up, what "context flows down" rules out (the facade re-entered from below).
Calling a lower module again after it returned is a new hand-off, not a re-entry. Measured at two levels:
- sub-packages (planner/search, planner/shots, ..., a top-level module such as planner/space.py or shot_request.py
  counts as its own): 0, on both request paths (random starts: ranked candidates; a given start: Planner.plan);
- modules: 0 as well. (Before: on the given-start path Planner.plan handed its Planner to shots/plan_request.py
  and shots/stages.py, which called back into shots/planner.py 15 times: ``space``, ``ready()``, ``checked_point``,
  ``checked_start``, ``check_timing``, ``obstacle_set``. Planner.plan now checks the inputs itself and hands the
  stages the PlanningSpace.)
Worker threads (host_pool) and forked candidate workers are not traced (none fork on this 2-core box)."""
from __future__ import annotations

import sys
from collections import Counter

import pytest

import cinenerf_ns.shot_request as shot_request
from cinenerf_ns.cli.plan_args import PlanArgs
from cinenerf_ns.cli.plan_run import run_plan
from cinenerf_ns.planner.config import PlannerConfig


def unit(module: str) -> str:
    """The sub-package a module belongs to: 'planner.search', 'planner.space', 'shot_request', 'viewer', ..."""
    parts = module.split(".")[1:]
    return ".".join(parts[:2]) if parts[:1] == ["planner"] else parts[0]


def trace(fn, top_code) -> list:
    """Run fn() under sys.setprofile; returns, per Python call made while a frame of ``top_code`` is on the stack, the
    chain [(module, function), ...] of cinenerf_ns frames from that frame down to the callee."""
    chains = []

    def profile(frame, event, arg):
        if event != "call" or not frame.f_globals.get("__name__", "").startswith("cinenerf_ns."):
            return
        chain, f = [], frame
        while f is not None:
            mod = f.f_globals.get("__name__", "")
            if mod.startswith("cinenerf_ns."):
                chain.append((mod, f.f_code.co_name))
            if f.f_code is top_code:
                chains.append(chain[::-1])
                return
            f = f.f_back

    sys.setprofile(profile)
    try:
        fn()
    finally:
        sys.setprofile(None)
    return chains


def re_entries(chains: list, level=lambda m: m) -> Counter:
    """{(caller 'module:function', callee 'module:function'): count} of the calls that re-enter (module docstring),
    modules grouped by ``level``."""
    out = Counter()
    for chain in chains:
        if len(chain) < 2:
            continue
        (callee, fn), (caller, cfn) = chain[-1], chain[-2]
        if level(callee) != level(caller) and level(callee) in {level(m) for m, _ in chain[:-2]}:
            out[(f"{caller}:{cfn}", f"{callee}:{fn}")] += 1
    return out


def hand_offs(chains: list) -> list:
    """The package-to-package hand-offs in call order: (caller unit, callee unit) of each call crossing units."""
    return [(unit(c[-2][0]), unit(c[-1][0])) for c in chains if len(c) > 1 and unit(c[-2][0]) != unit(c[-1][0])]


def test_re_entry_finder_finds_a_call_back_up():
    """Planted chains: a -> b -> a is a re-entry (b calls back into a); a -> b, then a -> b again is not."""
    chains = [[("cinenerf_ns.a", "f")], [("cinenerf_ns.a", "f"), ("cinenerf_ns.b", "g")],
              [("cinenerf_ns.a", "f"), ("cinenerf_ns.b", "g"), ("cinenerf_ns.a", "h")],
              [("cinenerf_ns.a", "f"), ("cinenerf_ns.b", "g2")]]
    assert re_entries(chains) == Counter({("cinenerf_ns.b:g", "cinenerf_ns.a:h"): 1})
    assert hand_offs(chains) == [("a", "b"), ("b", "a"), ("a", "b")]


@pytest.mark.parametrize("start", [None, "-0.3 0.3 0.2"], ids=["random-starts", "given-start"])
def test_a_cinesplat_plan_request_re_enters_no_module_it_has_left(tmp_path, start):
    args = PlanArgs(scene="procedural:20000", go_to="0.2 -0.2 0.1", look_at="0 0 0", start=start, candidates=2,
                    output_dir=tmp_path, planner=PlannerConfig(grid_resolution=48))  # a coarser grid: a quicker prepare
    chains = trace(lambda: run_plan(args), shot_request.plan_request.__code__)
    modules = {m for c in chains for m, _ in c}
    hops = hand_offs(chains)
    # the request went down through the stages (not a trace of nothing) ...
    assert {"cinenerf_ns.planner.search.coarse_path", "cinenerf_ns.planner.corridor.safe_corridor",
            "cinenerf_ns.planner.trajectory.qp", "cinenerf_ns.planner.geometry.clearance_queries"} <= modules, modules
    assert ("shot_request", "planner.shots") in hops and len(hops) > 50
    # ... handing off from package to package, never back into one it had left
    assert not re_entries(chains, unit), re_entries(chains, unit)
    assert not re_entries(chains), re_entries(chains)
    print(f"\n{len(chains)} calls, {len(modules)} modules, {len(hops)} package hand-offs "
          f"({len(set(hops))} distinct), module re-entries {sum(re_entries(chains).values())}")
