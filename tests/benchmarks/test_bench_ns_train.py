"""bench_ns_train.py without a GPU: its listener records nerfstudio's own step timer (a fake training loop through
the real writer / TimeWriter), its statistics and table, and every variant's ns-train arguments parse with
nerfstudio's own CLI into the intended config. The timings themselves come from GPU runs (benchmarks/RESULTS.md)."""
import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

import bench_ns_train as b  # noqa: E402


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
