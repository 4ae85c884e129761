"""The suite's own scheduling under `make test` (pytest-xdist, --dist loadgroup; tests/_xdist.py): free_port never
hands one port to two tests of a run, the headless-Chromium tests are one unit of work of the scheduler, and the
end-to-end tests (marked slow) are collected first."""
from __future__ import annotations

import socket

import pytest
from _xdist import GROUPS, free_port, reserve, scheduler_class


def test_free_port_never_hands_out_a_port_twice_in_a_run(tmp_path):
    ports = [free_port(tmp_path) for _ in range(30)]
    assert len(set(ports)) == 30
    assert all(not reserve(p, tmp_path) for p in ports)  # another worker asking gets another port
    with socket.socket() as s:  # each is free: it binds
        s.bind(("127.0.0.1", ports[-1]))


def test_the_browser_tests_are_one_unit_of_work(request):
    """Every test marked browser (and only those) is in the scheduler's "browser" group, whatever runs this test; with
    `make test` (--dist loadgroup) the scheduler xdist uses is the one of tests/_xdist.py."""
    pytest.importorskip("xdist")
    cls = scheduler_class()
    sched = cls.__new__(cls)  # _split_scope reads only the node id (a full scheduler needs the controller's nodes)
    grouped = {"tests/method/test_ns_train_cli.py": "ns-train"}  # files whose tests share one module fixture
    for item in request.session.items:
        want = "browser" if "browser" in item.keywords else grouped.get(item.nodeid.split("::")[0], item.nodeid)
        assert sched._split_scope(item.nodeid) == want, item.nodeid
    assert set(GROUPS.values()) == {"browser", "ns-train"}
    assert {f: g for f, g in GROUPS.items() if g != "browser"} == grouped
    hooks = request.config.hook.pytest_xdist_make_scheduler.get_hookimpls()
    assert any(h.plugin_name.endswith("conftest.py") for h in hooks), [h.plugin_name for h in hooks]


def test_the_slow_tests_are_collected_first(request):
    """tests/conftest.py puts the tests marked slow before all others (xdist hands out single tests in that order), and
    keeps the order of the rest."""
    items = request.session.items
    slow = ["slow" in item.keywords for item in items]
    if not any(slow) or all(slow):
        pytest.skip("this run collected no slow test, or only slow ones")
    assert slow == sorted(slow, reverse=True), [item.nodeid for item in items if "slow" in item.keywords]
