"""gc_pause.paused_gc and Planner.request_scope: the cyclic collector is off inside a request and back as it was
after it (nested, pre-disabled, exceptions, pause_gc=False)."""
from __future__ import annotations

import gc
from types import SimpleNamespace

import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.gc_pause import paused_gc
from cinenerf_ns.planner.shots import planner as planner_mod
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig


@pytest.fixture(autouse=True)
def collector_on():
    gc.enable()
    yield
    gc.enable()


def test_paused_inside_restored_after_and_on_errors():
    with paused_gc():
        assert not gc.isenabled()
        with paused_gc():  # nested: the inner one leaves it off
            assert not gc.isenabled()
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(ValueError), paused_gc():
        raise ValueError("boom")
    assert gc.isenabled()
    with paused_gc(False):
        assert gc.isenabled()


def test_a_collector_found_off_stays_off():
    gc.disable()
    with paused_gc():
        assert not gc.isenabled()
    assert not gc.isenabled()


def test_plan_runs_with_the_collector_paused(monkeypatch):
    seen = []
    monkeypatch.setattr(planner_mod, "plan_request", lambda *a, **k: seen.append(gc.isenabled()) or [])
    for pause, want in ((True, False), (False, True)):
        pl = Planner.__new__(Planner)  # request_scope needs only the config and the scene's device
        pl.config = PlannerConfig(pause_gc=pause)
        pl.scene = pl.batch_scene = SimpleNamespace(device=torch.device("cpu"))
        pl.plan([0, 0, 0], [1, 0, 0])
        assert seen[-1] is want
        assert gc.isenabled()


@pytest.mark.parametrize("bad", [0, 1, "yes", None])
def test_pause_gc_is_validated(bad):
    with pytest.raises(InvalidInputError, match="pause_gc must be True or False"):
        PlannerConfig(pause_gc=bad).validate()
