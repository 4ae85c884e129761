"""Shared pytest set-up: GPU / fox-data markers skip with a reason when unavailable."""
from __future__ import annotations

import gc
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

REPO = Path(__file__).resolve().parents[1]

# Property tests (hypothesis): `make test` runs them derandomised, the same examples on every run and machine (the
# examples follow from each test's source), with no example database (.hypothesis/ of earlier runs changes nothing);
# the cases a random run once found are pinned with @example. `make fuzz` (--hypothesis-profile=fuzz) draws random
# examples, FUZZ_FACTOR times each test's max_examples (see pytest_collection_modifyitems); a failure prints the
# @reproduce_failure blob to pin. Neither profile times anything (no deadline, no too_slow health check: a loaded
# machine must not fail a test). Registered before any test module builds its @settings (they inherit from the
# profile loaded at that moment).
UNTIMED = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True)
settings.register_profile("ci", derandomize=True, database=None, **UNTIMED)
settings.register_profile("fuzz", derandomize=False, **UNTIMED)
settings.load_profile("ci")
FUZZ_FACTOR = int(os.environ.get("FUZZ_FACTOR", "10"))

FOX = Path(os.environ.get("CINENERF_FOX", REPO.parent / "shared" / "data" / "fox"))
FOX_SPLAT = Path(os.environ.get("CINENERF_FOX_SPLAT",
                                REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz"))  # trained fox


def _cuda() -> bool:
    try:
        import torch

        return torch.cuda.is_available()
    except Exception:  # pragma: no cover
        return False


def _fuzz_more_examples(items) -> None:
    """The fuzz profile: each property test's own max_examples (its @settings) times FUZZ_FACTOR. Hypothesis has no
    option for this; the settings a @given test runs with are its _hypothesis_internal_use_settings."""
    from hypothesis import is_hypothesis_test

    done = set()
    for item in items:
        fn = getattr(getattr(item, "obj", None), "__func__", getattr(item, "obj", None))
        if fn is None or id(fn) in done or not is_hypothesis_test(fn):
            continue
        done.add(id(fn))
        own = fn._hypothesis_internal_use_settings
        fn._hypothesis_internal_use_settings = settings(own, max_examples=own.max_examples * FUZZ_FACTOR)


def pytest_collection_modifyitems(config, items):
    if settings.get_current_profile_name() == "fuzz":
        _fuzz_more_examples(items)
    # The end-to-end tests (marked slow, 10-25 s each) first: xdist hands out single tests in collection order, and
    # one of them drawn last kept one worker busy alone for its whole length (both workers end together instead).
    # Then the viewer's: many wait on servers, pages and played shots (1-2.4 s each, idle), and last in file order
    # they kept one worker waiting while the other had finished; the short computing tests end the run instead.
    items.sort(key=lambda item: ("slow" not in item.keywords, not item.nodeid.startswith("tests/viewer/")))
    has_cuda = _cuda()
    has_fox = (FOX / "transforms.json").exists()
    for item in items:
        if "gpu" in item.keywords and not has_cuda:
            item.add_marker(pytest.mark.skip(reason="needs a CUDA device (run scripts/gpu_check.sh on a GPU machine)"))
        if "fox" in item.keywords and not has_fox:
            item.add_marker(pytest.mark.skip(reason=f"sample scene not found at {FOX} "
                                             "(../shared/data/fox beside the checkout)"))


def pytest_collection_finish(session):
    """A full garbage collection walks every object the process tracks: after collection about 620,000 (torch,
    nerfstudio, the test items), alive until the session ends. Frozen, they are skipped, and a full collection comes
    at most every 100 middle ones (Python: 10). On the 2-core box the two workers' full collections took 10.3 s of CPU
    in a `make test`, 4.5 s with both (benchmarks/RESULTS.md). Young objects are collected as before."""
    gc.freeze()
    gen0, gen1, _ = gc.get_threshold()
    gc.set_threshold(gen0, gen1, 100)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """`make test` (--dist loadgroup): the browser tests on one worker (tests/_xdist.py says why and how)."""
    if config.getvalue("dist") == "loadgroup":
        import _xdist

        return _xdist.make_scheduler(config, log)
    return None


@pytest.fixture(scope="session", autouse=True)
def _ports_of_this_run(tmp_path_factory):
    """Under xdist, the run's folder where free_port (tests/_xdist.py) records the ports it hands out: the parent of the
    workers' basetemps (popen-gw0, popen-gw1, ...), which pytest removes with old runs."""
    import _xdist

    if os.environ.get("PYTEST_XDIST_WORKER"):
        _xdist.RUN_DIR = tmp_path_factory.getbasetemp().parent / "ports"
    yield


@pytest.fixture(scope="session")
def fuzz_factor() -> int:
    """How many times its own max_examples a property test runs under `make fuzz`."""
    return FUZZ_FACTOR


@pytest.fixture(scope="session")
def fox_dir() -> Path:
    return FOX


@pytest.fixture(scope="session")
def fox_splat() -> Path:
    """../shared/data/fox_cinesplat/fox3000.npz, a real capture's compact export (skips when it is absent)."""
    if not FOX_SPLAT.exists():
        pytest.skip(f"real-capture splat not found at {FOX_SPLAT} (../shared/data beside the checkout)")
    return FOX_SPLAT
