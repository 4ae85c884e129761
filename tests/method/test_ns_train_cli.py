"""Stock nerfstudio's command line with the cinesplat plugin installed, in one fresh Python process (nerfstudio's
method list costs ~11 s of CPU to import; three processes paid it three times):

1. stock eval_setup's path: yaml.load(config.yml) then torch.load(ckpt) with torch's weights_only default works
   once the config's import registered the safe globals (and fails before it: the failure is real on this torch);
2. the installed `ns-train --help` (its console script, run as its file) lists both methods (the
   nerfstudio.method_configs entry point is installed);
3. `ns-train cinesplat` with a number out of range stops with one line naming the flag, exit status 2, before
   config.yml or anything else is written.

The parts run in that order (1 needs a process where nothing of cinenerf_ns.method is imported yet); each part's
stdout and stderr are told apart by a marker line, and each test below checks its own part. The tests of this file run
on one xdist worker (tests/_xdist.py GROUPS), so the process runs once per `make test`."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from cinenerf_ns.method.cinesplat_config import make_cinesplat_config

REPO = Path(__file__).resolve().parents[2]
MARK = "=== cinenerf_ns test part: "
RUNNER = textwrap.dedent(
    """
    import inspect, io, pickle, runpy, sys, traceback

    config_yml, ns_train, data, outputs, tests_dir = sys.argv[1:6]
    # nerfstudio reads inspect.stack()[2].function 26 times while its method list is built: the same frames and
    # names without each frame's source-file lookup (tests/_ns_stack.py says why)
    sys.path.insert(0, tests_dir)
    from _ns_stack import stack_without_sources
    inspect.stack = stack_without_sources

    def part(name):
        for f in (sys.stdout, sys.stderr):
            print(f"{MARK}{name}", file=f, flush=True)

    def yaml_part():
        import numpy as np, torch, yaml
        buf = io.BytesIO(); torch.save({"lr": [np.float64(0.5)]}, buf)
        try:
            buf.seek(0); torch.load(buf, weights_only=True); print("LOADED-BEFORE")
        except pickle.UnpicklingError:
            print("FAILED-BEFORE")
        assert "cinenerf_ns.method" not in sys.modules
        cfg = yaml.load(open(config_yml).read(), Loader=yaml.Loader)
        assert "cinenerf_ns.method.compat" in sys.modules
        buf.seek(0); print("AFTER", torch.load(buf, weights_only=True))

    def help_part():
        sys.argv = [ns_train, "--help"]
        runpy.run_path(ns_train, run_name="__main__")  # the console script: sys.exit(entrypoint())

    def stop_part():
        from nerfstudio.scripts.train import entrypoint
        sys.argv = ["ns-train", "cinesplat", "--data", data, "--output-dir", outputs,
                    "--pipeline.model.latent-every", "0"]
        entrypoint()

    for name, fn in (("yaml", yaml_part), ("help", help_part), ("stop", stop_part)):
        part(name)
        code = 0
        try:
            fn()
        except SystemExit as e:
            code = e.code
        except BaseException:
            traceback.print_exc()
            code = "exception"
        sys.stdout.flush(); sys.stderr.flush()
        print(f"EXIT {code}", flush=True)
    """
).replace("{MARK}", MARK)


def _split(text: str) -> dict:
    parts, name = {}, None
    for line in text.splitlines(keepends=True):
        if line.startswith(MARK):
            name = line[len(MARK):].strip()
            parts[name] = ""
        elif name is not None:
            parts[name] += line
    return parts


@pytest.fixture(scope="module")
def ns_train_parts(tmp_path_factory) -> dict:
    """{part: {"out": stdout, "err": stderr, "exit": its exit status as text}} of the one process."""
    exe = shutil.which("ns-train") or str(Path(sys.executable).parent / "ns-train")
    if not Path(exe).exists():
        pytest.skip("ns-train is not installed in this environment")
    tmp = tmp_path_factory.mktemp("ns_train")
    (tmp / "config.yml").write_text(yaml.dump(make_cinesplat_config()))
    r = subprocess.run([sys.executable, "-c", RUNNER, str(tmp / "config.yml"), exe, str(tmp / "no_data"),
                        str(tmp / "outputs"), str(REPO / "tests")], cwd=REPO, capture_output=True, text=True,
                       timeout=300, env={**os.environ, "COLUMNS": "200"})
    out, err = _split(r.stdout), _split(r.stderr)
    assert r.returncode == 0 and set(out) == {"yaml", "help", "stop"}, r.stdout[-3000:] + r.stderr[-3000:]
    res = {}
    for name, text in out.items():
        body, _, status = text.rstrip("\n").rpartition("\n")
        if not status.startswith("EXIT "):  # a part that printed nothing: the whole text is the status line
            body, status = "", text.strip()
        res[name] = {"out": body, "err": err.get(name, ""), "exit": status[len("EXIT "):], "outputs": tmp / "outputs"}
    return res


def test_yaml_load_of_config_registers_safe_globals(ns_train_parts):
    """Stock eval_setup: yaml.load(config.yml) then torch.load(ckpt) with torch's default weights_only."""
    p = ns_train_parts["yaml"]
    assert p["exit"] == "0", p["err"][-2000:]
    assert "FAILED-BEFORE" in p["out"]  # the failure is real on this torch...
    assert "AFTER {'lr': [np.float64(0.5)]}" in p["out"]  # ...and gone after the config import


def test_ns_train_help_lists_cinesplat(ns_train_parts):
    """The nerfstudio.method_configs entry point is installed: stock `ns-train --help` lists both methods."""
    p = ns_train_parts["help"]
    assert p["exit"] == "0", p["err"][-2000:]
    assert "cinesplat" in p["out"] and "cinesplat-lite" in p["out"]


def test_ns_train_stops_before_writing_anything(ns_train_parts):
    """A number out of range (cinenerf_ns/method/config_ranges.py) stops ns-train before it writes anything."""
    p = ns_train_parts["stop"]
    text = p["out"] + p["err"]
    assert p["exit"] == "2", text[-2000:]
    assert "--pipeline.model.latent-every must be an integer in [1, 1e+06], got 0" in text
    assert "Traceback" not in text
    assert not p["outputs"].exists()
