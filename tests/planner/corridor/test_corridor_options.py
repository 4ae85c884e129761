"""corridor_options.corridor_backend's resolution, on fake planning spaces whose scenes claim a CUDA device (no GPU
needed)."""
from types import SimpleNamespace

import pytest
import torch

from cinenerf_ns.planner.corridor import corridor_options
from cinenerf_ns.planner.shots import candidates
from cinenerf_ns.planner.shots.planner import PlannerConfig


def _fake(backend: str, batch_dev: str, request_dev: str):
    cfg = PlannerConfig(corridor_backend=backend)
    return SimpleNamespace(config=cfg, batch_scene=SimpleNamespace(device=torch.device(batch_dev)),
                           scene=SimpleNamespace(device=torch.device(request_dev)))


@pytest.mark.parametrize("batch_dev,request_dev,one,many", [
    ("cpu", "cpu", "cpu", "cpu"),           # CPU scene
    ("cuda", "cpu", "cpu", "batched"),      # CUDA scene, requests on its CPU mirror (request_device 'auto')
    ("cuda", "cuda", "batched", "batched"),  # requests on the CUDA scene itself (request_device 'scene')
])
def test_auto_host_polytopes_for_one_request_batched_for_many(monkeypatch, batch_dev, request_dev, one, many):
    monkeypatch.setattr(corridor_options, "in_worker", lambda: False)
    monkeypatch.setattr(torch.cuda, "_is_in_bad_fork", lambda: False)
    pl = _fake("auto", batch_dev, request_dev)
    assert corridor_options.corridor_backend(pl) == one
    assert corridor_options.corridor_backend(pl, many=True) == many
    for b in ("cpu", "batched"):  # explicit choices are kept
        assert corridor_options.corridor_backend(_fake(b, batch_dev, request_dev)) == b
        assert corridor_options.corridor_backend(_fake(b, batch_dev, request_dev), many=True) == b


def test_worker_and_bad_fork_always_cpu(monkeypatch):
    monkeypatch.setattr(corridor_options, "in_worker", lambda: True)
    for b in ("auto", "batched"):
        assert corridor_options.corridor_backend(_fake(b, "cuda", "cuda"), many=True) == "cpu"
    monkeypatch.setattr(corridor_options, "in_worker", lambda: False)
    monkeypatch.setattr(torch.cuda, "_is_in_bad_fork", lambda: True)
    assert corridor_options.corridor_backend(_fake("batched", "cuda", "cpu"), many=True) == "cpu"


def test_candidates_two_phase_rounds_follow_the_many_corridor_backend(monkeypatch):
    monkeypatch.setattr(corridor_options, "in_worker", lambda: False)
    for batch_dev, grid, want in (("cuda", False, candidates._round_two_phase),
                                  ("cuda", True, candidates._round_in_workers),
                                  ("cpu", False, candidates._round_in_workers)):
        space = _fake("auto", batch_dev, "cpu")  # the planning space's fields corridor_backend reads
        monkeypatch.setattr(candidates, "use_grid_polytopes", lambda _space, grid=grid: grid)
        req = SimpleNamespace(planner=SimpleNamespace(space=space), pool=object())
        assert candidates._round_strategy(req) is want
    assert candidates._round_strategy(SimpleNamespace(planner=req.planner, pool=None)) is candidates._round_in_process


def test_corridor_threads_resolution(monkeypatch):
    assert PlannerConfig().corridor_threads == 1  # the default (docs/PLANNER_DEFAULTS.md)
    monkeypatch.setattr(corridor_options, "in_worker", lambda: False)
    monkeypatch.setattr(corridor_options, "usable_cpus", lambda: 16)
    auto = _fake("auto", "cpu", "cpu")
    auto.config.corridor_threads = None
    assert corridor_options.corridor_threads(auto) == corridor_options.CORRIDOR_THREADS_MAX
    monkeypatch.setattr(corridor_options, "usable_cpus", lambda: 2)
    assert corridor_options.corridor_threads(auto) == 2
    pl = _fake("auto", "cpu", "cpu")
    pl.config.corridor_threads = 3
    assert corridor_options.corridor_threads(pl) == 3
    monkeypatch.setattr(corridor_options, "in_worker", lambda: True)  # one process per core already
    assert corridor_options.corridor_threads(pl) == 1


@pytest.mark.parametrize("bad", [0, -2, 1.5, True, "4"])
def test_corridor_threads_is_validated(bad):
    from cinenerf_ns.planner.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="corridor_threads must be None"):
        PlannerConfig(corridor_threads=bad).validate()
