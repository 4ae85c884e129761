"""bench_ns_train.py without a GPU: its listener records nerfstudio's own step timer (a fake training loop through
the real writer / TimeWriter), its statistics and table, and every variant's ns-train arguments parse with
nerfstudio's own CLI into the intended config. The timings themselves come from GPU runs (benchmarks/RESULTS.md)."""
import inspect
import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

import bench_ns_train as b  # noqa: E402
from _ns_stack import stack_without_sources  # noqa: E402


@pytest.fixture(autouse=True)
def _stack_without_source_lines(monkeypatch):
    """nerfstudio builds its method list (nerfstudio.configs.method_configs, imported by whichever test comes first)
    reading inspect.stack()[2].function 26 times: the same frames and names without each frame's source-file lookup
    (tests/_ns_stack.py says why; test_ns_train_cli.py's runner does the same)."""
    monkeypatch.setattr(inspect, "stack", stack_without_sources)


def test_child_records_nerfstudios_step_timer(tmp_path):
    from nerfstudio.configs.base_config import LoggingConfig
    from nerfstudio.utils import writer
    from nerfstudio.utils.writer import EventName, TimeWriter

    seen_argv = []

    def fake_ns_train():  # what Trainer.train does around each step, with the real writer
        seen_argv.append(list(sys.argv))
        writer.setup_local_writer(LoggingConfig(), max_iter=30)
        for step in range(30):
            with TimeWriter(writer, EventName.ITER_TRAIN_TIME, step=step):
                pass
            writer.put_time(EventName.TRAIN_RAYS_PER_SEC, 1.0, step=step)  # other timers are not recorded

    from nerfstudio.engine import trainer as trainer_mod

    put_time, train = writer.put_time, trainer_mod.Trainer.train
    out = tmp_path / "r.json"
    old_argv = list(sys.argv)
    try:
        b.child(out, ["splatfacto", "--data", "x"], entry=fake_ns_train)
    finally:
        sys.argv = old_argv
    assert seen_argv == [["ns-train", "splatfacto", "--data", "x"]]
    res = json.loads(out.read_text())
    assert [s for s, _ in res["raw"]] == list(range(30)) and len(res["console"]) == 30
    assert all(d >= 0 for _, d in res["raw"])
    # the console's value is nerfstudio's running mean over the last max_buffer_size steps
    bs = LoggingConfig().max_buffer_size
    d = [x for _, x in res["raw"]]
    assert res["console"][-1] == pytest.approx(sum(d[-bs:]) / bs)
    # the listeners are removed afterwards
    assert writer.put_time is put_time and trainer_mod.Trainer.train is train


def test_window_stats_and_table():
    def fake(ms_per_step, peak, psnr):
        raw = [[s, (ms_per_step + (5 if s == 1500 else 0)) / 1000] for s in range(3000)]
        return {"raw": raw, "console": [d for _, d in raw], "gaussians": 1000, "peak_mem_mib": peak,
                "eval": {"psnr": psnr, "ssim": 0.8, "lpips": float("nan")}, "first_step_s": 12.0}

    rows = []
    for name, ms, peak in (("splatfacto", 10.0, 1000.0), ("cinesplat", 11.0, 1100.0)):
        res = fake(ms, peak, 20.0)
        rows.append({"name": name, "downscale": 4, "repeat": 0, "result": res,
                     "stats": b.window_stats(res, 1000, 3000)})
    st = rows[1]["stats"]
    assert st["n"] == 2000 and st["median"] == pytest.approx(11.0) and st["max"] == pytest.approx(16.0)
    assert st["p95"] == pytest.approx(11.0)
    lines = b.table(rows, 1000, 3000)
    assert "| cinesplat | 4 | 11.00 |" in lines[3] and "| 1.100 |" in lines[3] and "| 1.10 |" in lines[3]
    assert "n/a" in lines[3]  # NaN LPIPS (no AlexNet weights offline)
    assert "| nan |" in lines[3]  # no setup peak recorded in this fake
    assert b.percentile([1, 2, 3, 4, 5], 50) == 3 and b.percentile([1, 2], 95) == pytest.approx(1.95)
    assert b.window_stats({"raw": []}, 0, 10) == {"n": 0}
    ratios = b.window_ratios(rows, [0, 1000, 2000, 3000])
    assert ratios[0] == "| run | ds | 0-1000 | 1000-2000 | 2000-3000 |"
    assert ratios[2] == "| cinesplat | 4 | 1.100 | 1.100 | 1.100 |"


def test_runs_spec_and_every_variant_parses_with_ns_train_cli():
    import tyro
    from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion

    assert b.parse_runs("splatfacto@4, cinesplat@2") == [("splatfacto", 4), ("cinesplat", 2)]
    with pytest.raises(SystemExit):
        b.parse_runs("nope@4")
    expect = {"cinesplat": ("shared", "image", 2, 0), "cinesplat-separate": ("separate", "image", 2, 0),
              "cinesplat-fused": ("fused", "image", 2, 0), "cinesplat-feature": ("separate", "feature", 2, 0),
              "cinesplat-every1": ("shared", "image", 1, 0), "cinesplat-every3": ("shared", "image", 3, 0),
              "cinesplat-nolatent": ("shared", "image", 2, 100000000)}
    for name in b.VARIANTS:
        cfg = tyro.cli(AnnotatedBaseConfigUnion,
                       args=b.ns_train_args(name, Path("/data/fox"), 2, 3000, Path("/tmp/w"), "t", "viewer"))
        assert cfg.max_num_iterations == 3000 and cfg.viewer.quit_on_train_completion
        assert cfg.pipeline.datamanager.dataparser.downscale_factor == 2 and cfg.machine.seed == 42
        m = cfg.pipeline.model
        if name == "splatfacto":
            assert cfg.method_name == "splatfacto"
            continue
        assert cfg.method_name == "cinesplat" and cfg.pipeline.datamanager.clip.random_weights
        got = (m.latent_render_mode, m.latent_render_resolution, m.latent_every, m.latent_start_step)
        assert got == expect.get(name, ("shared", "image", 2, 0)), name


def test_lane_queues_latin_runs_every_cell_on_every_gpu_and_deal_splits():
    runs = [("splatfacto", 4), ("cinesplat", 4), ("splatfacto", 2), ("cinesplat", 2)]
    assert b.lane_queues(runs, 2, 1, "latin") == [[(n, d, r) for r in range(2) for n, d in runs]]
    q = b.lane_queues(runs, 1, 4, "latin")
    assert [len(x) for x in q] == [4, 4, 4, 4]
    for k, lane in enumerate(q):
        assert sorted((n, d) for n, d, _ in lane) == sorted(runs)  # every cell on every GPU
        assert {r for _, _, r in lane} == {k}  # a ratio compares two runs of one GPU
    for slot in range(4):  # at any moment the lanes run four different cells
        assert len({q[k][slot][:2] for k in range(4)}) == 4
    q2 = b.lane_queues(runs, 2, 4, "latin")
    assert [r for _, _, r in q2[1]] == [1] * 4 + [5] * 4
    d = b.lane_queues(runs, 1, 4, "deal")
    assert d == [[("splatfacto", 4, 0)], [("cinesplat", 4, 0)], [("splatfacto", 2, 0)], [("cinesplat", 2, 0)]]
    assert b.lane_queues(runs[:2], 1, 3, "deal") == [[("splatfacto", 4, 0)], [("cinesplat", 4, 0)], []]


def test_cpu_split_gives_disjoint_equal_slices():
    import os

    cpus = sorted(os.sched_getaffinity(0))
    sl = b.cpu_split(2)
    assert len(sl) == 2
    if len(cpus) >= 2:
        assert not set(sl[0]) & set(sl[1]) and len(sl[0]) == len(sl[1]) == len(cpus) // 2
    assert b.ratio_window(3000) == 500 and b.ratio_window(30000) == 5000 and b.ratio_window(1000) == 500


def test_summary_over_repeats():
    def row(name, rep, ms, psnr, mem=100.0):
        return {"name": name, "downscale": 4, "repeat": rep, "stats": {"n": 10, "median": ms},
                "result": {"peak_mem_mib": mem, "eval": {"psnr": psnr, "ssim": 0.5}}}

    rows = [row("splatfacto", 0, 10.0, 20.0), row("cinesplat", 0, 11.0, 20.1, 110.0),
            row("splatfacto", 1, 12.0, 20.0), row("cinesplat", 1, 12.6, 19.8, 120.0),
            row("splatfacto", 2, 10.0, 20.0), row("cinesplat", 2, 10.8, 20.0, 100.0),
            row("cinesplat", 3, 99.0, 0.0)]  # no splatfacto of repeat 3: not paired
    out = b.summary(rows)
    assert out[2] == ("| cinesplat | 4 | 3 | 1.080 [1.050, 1.100] | 1.10 [1.00, 1.20] | +0.00 [-0.20, +0.10] | "
                      "+0.0000 [+0.0000, +0.0000] |")


def test_child_stops_at_the_deadline_and_keeps_the_steps(tmp_path, monkeypatch):
    from nerfstudio.configs.base_config import LoggingConfig
    from nerfstudio.utils import writer
    from nerfstudio.utils.writer import EventName, TimeWriter

    done = []

    def fake_ns_train():
        writer.setup_local_writer(LoggingConfig(), max_iter=30)
        for step in range(30):
            with TimeWriter(writer, EventName.ITER_TRAIN_TIME, step=step):
                pass
            done.append(step)

    monkeypatch.setenv("BENCH_NS_TRAIN_DEADLINE", "0")  # long past: the first step's timer ends training
    out = tmp_path / "r.json"
    old_argv = list(sys.argv)
    try:
        b.child(out, ["splatfacto"], entry=fake_ns_train)
    finally:
        sys.argv = old_argv
    res = json.loads(out.read_text())
    assert res["stopped_at_step"] == 0 and [s for s, _ in res["raw"]] == [0] and done == []


def test_child_stops_a_real_trainer_loop_through_stop_training(tmp_path, monkeypatch):
    """With a Trainer, the deadline sets ``stop_training`` (nerfstudio's own way out of the loop): the loop ends after
    that step and the run is still measured and evaluated like one that reached its last step."""
    from types import SimpleNamespace

    from nerfstudio.configs.base_config import LoggingConfig
    from nerfstudio.engine import trainer as trainer_mod
    from nerfstudio.utils import writer
    from nerfstudio.utils.writer import EventName, TimeWriter

    def loop(self):  # Trainer.train's loop, reduced to what the listener relies on
        writer.setup_local_writer(LoggingConfig(), max_iter=50)
        for step in range(50):
            if self.stop_training:
                break
            with TimeWriter(writer, EventName.ITER_TRAIN_TIME, step=step):
                pass
            self.step = step

    monkeypatch.setattr(trainer_mod.Trainer, "train", loop)  # the child wraps this one
    fake = SimpleNamespace(
        stop_training=False, step=0, config=SimpleNamespace(method_name="fake"),
        pipeline=SimpleNamespace(model=SimpleNamespace(num_points=7),
                                 get_average_eval_image_metrics=lambda step, get_std: {"psnr": 20.0 + step}))
    monkeypatch.setenv("BENCH_NS_TRAIN_DEADLINE", "0")
    out = tmp_path / "r.json"
    old_argv = list(sys.argv)
    try:
        b.child(out, ["fake"], entry=lambda: trainer_mod.Trainer.train(fake))
    finally:
        sys.argv = old_argv
    res = json.loads(out.read_text())
    assert fake.stop_training and res["stopped_at_step"] == 0 and [s for s, _ in res["raw"]] == [0]
    assert res["gaussians"] == 7 and res["eval"] == {"psnr": 20.0} and res["method"] == "fake"


@pytest.mark.parametrize("bad", [["--gpus", "0,a"], ["--gpus", "0,0"], ["--gpus", ""], ["--stop-after-s", "0"],
                                 ["--stop-after-s", "nan"]])
def test_bad_lane_options_stop_before_any_run(bad, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(b, "run_one", lambda *a, **k: pytest.fail("a run started"))
    with pytest.raises(SystemExit) as e:
        b.main(["--data", str(tmp_path), "--work", str(tmp_path / "w"), "--record", "none", *bad])
    assert e.value.code == 2 and bad[0] in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
