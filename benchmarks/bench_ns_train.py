#!/usr/bin/env python3
"""Training speed as the user sees it: stock ``ns-train`` runs of splatfacto and cinesplat variants (GPU).

    python benchmarks/bench_ns_train.py --data ../shared/data/fox \
        [--runs splatfacto@4,cinesplat@4,splatfacto@2,cinesplat@2] [--steps 3000] [--repeats 1]
        [--window 1000:3000] [--work /tmp/bench_ns_train] [--out-json FILE] [--record benchmarks/RESULTS.md|none]
        [--gpus 0,1,2,3 [--layout latin|deal]] [--stop-after-s S]

Every run is its own process running nerfstudio's ``ns-train`` entry point unchanged (same seed, same data, the
method's default schedule cut at ``--steps``, the default viewer with ``--viewer.quit-on-train-completion True``),
in the order given (``--repeats`` cycles through the whole list again: interleaved). With ``--gpus``, one lane of
runs per GPU runs in parallel, each child on its GPU and an equal slice of the host's cores (``lane_queues``).
The child process only listens:
* nerfstudio's own per-step timer: every duration the trainer's ``TimeWriter(ITER_TRAIN_TIME)`` hands to
  ``writer.put_time`` ("Train Iter (time)": host wall time of callbacks + forward + backward + optimizer, NOT
  CUDA-synchronised: a step's queued GPU work is paid by whichever later host sync waits for it) and the
  20-step running mean the console shows;
* at the end: Gaussian count, peak GPU memory of the training steps (``max_memory_allocated``; the peak is reset
  when training starts, so setup such as cinesplat's CLIP feature extraction is reported apart as "setup peak", and
  after each eval so eval renders do not count), eval PSNR / SSIM / LPIPS over the eval split
  (``pipeline.get_average_eval_image_metrics``). LPIPS needs torchvision's AlexNet weights, which stock splatfacto
  downloads; offline both methods build it through ``compat.offline_safe_lpips("cached")`` and it is reported
  n/a when the weights are not cached.
Reported per run over the step window (default 1000-3000): median, p95, max, mean of the per-step times and the
median of the console's running mean; ratios to splatfacto's median at the same downscale (per repeat), and over the
repeats their median [min, max]. ``--stop-after-s`` ends a run's training after S seconds through nerfstudio's own
``stop_training`` (the table says at which step) and measures it as after its last step.

Variants (``--runs NAME@DOWNSCALE``): see VARIANTS; cinesplat variants use random-weight CLIP (offline, same speed).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

_CINE = ["cinesplat", "--pipeline.datamanager.clip.random-weights", "True", "--pipeline.model.lpips", "cached"]
VARIANTS: Dict[str, List[str]] = {
    "splatfacto": ["splatfacto"],
    "cinesplat": list(_CINE),  # the defaults
    "cinesplat-shared": _CINE + ["--pipeline.model.latent-render-mode", "shared"],
    "cinesplat-separate": _CINE + ["--pipeline.model.latent-render-mode", "separate"],
    "cinesplat-fused": _CINE + ["--pipeline.model.latent-render-mode", "fused"],
    "cinesplat-feature": _CINE + ["--pipeline.model.latent-render-mode", "separate",
                                  "--pipeline.model.latent-render-resolution", "feature"],
    "cinesplat-every1": _CINE + ["--pipeline.model.latent-every", "1"],
    "cinesplat-every2": _CINE + ["--pipeline.model.latent-every", "2"],
    "cinesplat-every3": _CINE + ["--pipeline.model.latent-every", "3"],
    "cinesplat-nostream": _CINE + ["--pipeline.model.latent-side-stream", "False"],
    # the latent pass never runs: what cinesplat costs besides it (param group, viewer panel, datamanager)
    "cinesplat-nolatent": _CINE + ["--pipeline.model.latent-start-step", "100000000"],
}


# ------------------------------------------------------------------------------------------------ child process
class _StopTraining(Exception):
    """Ends a fake entry (no Trainer) at the deadline; a real Trainer is stopped through ``stop_training``."""


def child(result_path: Path, ns_train_args: Sequence[str], entry=None) -> None:
    """Run ns-train (``entry``: nerfstudio's entrypoint unless given) with listeners that write ``result_path``."""
    import torch
    from nerfstudio.engine import trainer as trainer_mod
    from nerfstudio.utils import writer as W
    from nerfstudio.utils.writer import EventName

    from cinenerf_ns.method.compat import offline_safe_lpips

    t_start = time.perf_counter()
    res: dict = {"args": list(ns_train_args), "raw": [], "console": [], "first_step_s": None}
    deadline = float(os.environ["BENCH_NS_TRAIN_DEADLINE"]) if os.environ.get("BENCH_NS_TRAIN_DEADLINE") else None
    holder: dict = {}  # the Trainer, once its train() starts
    cuda = torch.cuda.is_available()
    mem = {"train_peak": 0}
    name_iter = EventName.ITER_TRAIN_TIME.value
    orig_put_time = W.put_time

    def put_time(name, duration, step, avg_over_steps=True, update_eta=False):
        orig_put_time(name, duration, step, avg_over_steps, update_eta)
        if (name.value if isinstance(name, EventName) else name) == name_iter:
            if res["first_step_s"] is None:
                res["first_step_s"] = time.perf_counter() - t_start
            res["raw"].append([int(step), float(duration)])
            ev = W.GLOBAL_BUFFER.get("events", {}).get(name_iter)
            res["console"].append(float(ev["avg"]) if ev else float("nan"))
            if deadline is not None and time.time() > deadline and res.get("stopped_at_step") is None:
                res["stopped_at_step"] = int(step)  # a long schedule cut short: the loop ends after this step
                if "trainer" in holder:
                    holder["trainer"].stop_training = True
                else:
                    raise _StopTraining  # no Trainer (a fake entry): end here

    orig_eval_iteration = trainer_mod.Trainer.eval_iteration
    orig_train = trainer_mod.Trainer.train

    def eval_iteration(self, step):
        if cuda:
            mem["train_peak"] = max(mem["train_peak"], torch.cuda.max_memory_allocated())
        out = orig_eval_iteration(self, step)
        if cuda:
            torch.cuda.reset_peak_memory_stats()  # host-side counter reset, no device sync
        return out

    def train(self):
        holder["trainer"] = self
        if cuda:  # setup (CLIP features, codec fit) is not training: its peak is kept apart
            res["peak_mem_setup_mib"] = torch.cuda.max_memory_allocated() / 2**20
            torch.cuda.reset_peak_memory_stats()
        orig_train(self)
        res["train_s"] = time.perf_counter() - t_start - (res["first_step_s"] or 0.0)
        model = self.pipeline.model
        res["gaussians"] = int(model.num_points)
        res["method"] = str(self.config.method_name)
        if cuda:
            mem["train_peak"] = max(mem["train_peak"], torch.cuda.max_memory_allocated())
            res["peak_mem_mib"] = mem["train_peak"] / 2**20
            res["device"] = torch.cuda.get_device_name(0)
        t = time.perf_counter()
        try:
            metrics = self.pipeline.get_average_eval_image_metrics(step=self.step, get_std=False)
            res["eval"] = {k: float(v) for k, v in metrics.items() if isinstance(v, (int, float))}
        except Exception as e:  # the timing is the point; say why eval is missing
            res["eval_error"] = f"{type(e).__name__}: {e}"[:300]
        res["eval_s"] = time.perf_counter() - t
        _write_json(result_path, res)

    W.put_time = put_time
    trainer_mod.Trainer.eval_iteration = eval_iteration
    trainer_mod.Trainer.train = train
    real = entry is None
    if real:
        from nerfstudio.scripts.train import entrypoint as entry
    sys.argv = ["ns-train", *ns_train_args]
    try:
        with offline_safe_lpips("cached"):  # splatfacto's LPIPS would download AlexNet (cinesplat: its own option)
            entry()
    except _StopTraining:  # outside Trainer.train (a fake entry): the steps so far are the result
        pass
    finally:
        if not result_path.exists():  # crashed: keep the steps recorded so far
            _write_json(result_path, res)
        W.put_time = orig_put_time
        trainer_mod.Trainer.eval_iteration = orig_eval_iteration
        trainer_mod.Trainer.train = orig_train
    res["wall_s"] = time.perf_counter() - t_start
    _write_json(result_path, res)
    if real:  # results are written: leave now, whatever threads (viewer server, loaders) would keep the process alive
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


def _write_json(path: Path, obj) -> None:
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(json.dumps(obj))
    os.replace(tmp, path)


# ------------------------------------------------------------------------------------------------ statistics
def percentile(xs: Sequence[float], q: float) -> float:
    """Linear-interpolated percentile (q in [0, 100]) of a non-empty sequence."""
    s = sorted(xs)
    if not s:
        return float("nan")
    k = (len(s) - 1) * q / 100.0
    lo, hi = math.floor(k), math.ceil(k)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


def window_stats(res: dict, lo: int, hi: int) -> dict:
    """ms statistics of the steps lo <= step < hi of one child result (raw per-step times and console means)."""
    raw = [(s, d) for s, d in res.get("raw", [])]
    con = res.get("console", [])
    sel = [i for i, (s, _) in enumerate(raw) if lo <= s < hi]
    d = [1000.0 * raw[i][1] for i in sel]
    c = [1000.0 * con[i] for i in sel if i < len(con)]
    if not d:
        return {"n": 0}
    return {
        "n": len(d),
        "median": statistics.median(d),
        "p95": percentile(d, 95),
        "max": max(d),
        "mean": statistics.fmean(d),
        "console_median": statistics.median(c) if c else float("nan"),
    }


def parse_runs(spec: str) -> List[tuple]:
    """"a@4,b@2" -> [("a", 4), ("b", 2)], names checked against VARIANTS."""
    out = []
    for item in filter(None, (x.strip() for x in spec.split(","))):
        name, _, ds = item.partition("@")
        if name not in VARIANTS:
            raise SystemExit(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")
        out.append((name, int(ds or 4)))
    return out


def ns_train_args(name: str, data: Path, downscale: int, steps: int, work: Path, timestamp: str, vis: str) -> List[str]:
    return [
        *VARIANTS[name],
        "--data", str(data),
        "--output-dir", str(work / "outputs"),
        "--experiment-name", "bench",  # cinesplat runs share the feature cache <output>/bench/cinesplat_cache
        "--timestamp", timestamp,
        "--max-num-iterations", str(steps),
        "--vis", vis,
        "--viewer.quit-on-train-completion", "True",
        "nerfstudio-data", "--downscale-factor", str(downscale),
    ]


def table(rows: List[dict], lo: int, hi: int) -> List[str]:
    lines = [
        "| run | ds | step ms median | p95 | max | mean | console median | x splatfacto (median) | x (mean) | "
        "Gaussians | peak MiB | x mem | setup peak MiB | PSNR | SSIM | LPIPS | setup s | gpu |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    base: Dict[tuple, dict] = {}
    for r in rows:
        if r["name"] == "splatfacto" and r["stats"].get("n"):
            base.setdefault((r["downscale"], r["repeat"]), r)
    for r in rows:
        st = r["stats"]
        if not st.get("n"):
            lines.append(f"| {r['name']} | {r['downscale']} | failed: {r.get('error', 'no steps recorded')} |")
            continue
        b = base.get((r["downscale"], r["repeat"]))
        ratio = st["median"] / b["stats"]["median"] if b else float("nan")
        ratio_mean = st["mean"] / b["stats"]["mean"] if b else float("nan")
        pm = r["result"].get("peak_mem_mib", float("nan"))
        xm = pm / b["result"].get("peak_mem_mib", float("nan")) if b else float("nan")
        ev = r["result"].get("eval", {})
        f = lambda k, fmt: (fmt % ev[k]) if k in ev and ev[k] == ev[k] else "n/a"  # noqa: E731
        label = r["name"] + (f" ({r['error']})" if r.get("error") else "")
        lines.append(
            f"| {label} | {r['downscale']} | {st['median']:.2f} | {st['p95']:.2f} | {st['max']:.1f} | "
            f"{st['mean']:.2f} | {st['console_median']:.2f} | {ratio:.3f} | {ratio_mean:.3f} | "
            f"{r['result'].get('gaussians', 0)} | {pm:.0f} | {xm:.2f} | "
            f"{r['result'].get('peak_mem_setup_mib', float('nan')):.0f} | {f('psnr', '%.2f')} | {f('ssim', '%.4f')} | "
            f"{f('lpips', '%.4f')} | {r['result'].get('first_step_s') or float('nan'):.1f} | {r.get('gpu') or '-'} |"
        )
    return lines


def window_ratios(rows: List[dict], edges: Sequence[int]) -> List[str]:
    """Per run, its median step time in each window [edges[k], edges[k+1]) over splatfacto's at the same downscale and
    repeat: how the gap changes as training goes on (Gaussian count, SH degree)."""
    base = {(r["downscale"], r["repeat"]): r["result"] for r in rows if r["name"] == "splatfacto" and r["result"]}
    heads = [f"{a}-{b}" for a, b in zip(edges[:-1], edges[1:])]
    out = ["| run | ds | " + " | ".join(heads) + " |", "|---|---|" + "---|" * len(heads)]
    for r in rows:
        b = base.get((r["downscale"], r["repeat"]))
        if r["name"] == "splatfacto" or not b or not r["result"]:
            continue
        cells = []
        for lo, hi in zip(edges[:-1], edges[1:]):
            x, y = window_stats(r["result"], lo, hi), window_stats(b, lo, hi)
            cells.append(f"{x['median'] / y['median']:.3f}" if x.get("n") and y.get("n") else "n/a")
        out.append(f"| {r['name']} | {r['downscale']} | " + " | ".join(cells) + " |")
    return out


def lane_queues(runs: Sequence[tuple], repeats: int, n_lanes: int, layout: str) -> List[List[tuple]]:
    """The runs each lane (GPU) does in order, as (name, downscale, repeat).

    One lane: the list ``repeats`` times (interleaved). ``latin``: lane k runs the list rotated by k, ``repeats``
    times, so at any moment the lanes run different cells and every cell runs on every GPU; repeat = rep * n + k, so
    a ratio (same downscale and repeat) compares two runs on one GPU. ``deal``: the repeated list is dealt out, run i
    to lane i % n, repeat = rep: all runs at once (a long schedule), a ratio then compares two GPUs of one host."""
    if n_lanes == 1:
        return [[(n, d, r) for r in range(repeats) for n, d in runs]]
    if layout == "latin":
        return [[(n, d, r * n_lanes + k) for r in range(repeats) for n, d in (list(runs[k % len(runs):]) +
                                                                         list(runs[:k % len(runs)]))]
                for k in range(n_lanes)]
    flat = [(n, d, r) for r in range(repeats) for n, d in runs]
    return [flat[k::n_lanes] for k in range(n_lanes)]


def cpu_split(n_lanes: int) -> List[List[int]]:
    """The host's cores in n equal slices, one per lane: each ns-train sees a single-GPU machine's share."""
    cpus = sorted(os.sched_getaffinity(0))
    per = max(1, len(cpus) // n_lanes)
    return [cpus[k * per:(k + 1) * per] or cpus for k in range(n_lanes)]


def run_one(name: str, ds: int, rep: int, k: int, gpu: Optional[str], cpus: Optional[List[int]], args, logs: Path,
            lo: int, hi: int) -> dict:
    """One ns-train child process (on ``gpu`` and ``cpus`` when lanes are used); its row of results."""
    stamp = f"{name}_ds{ds}_r{rep}"
    work = args.work / f"lane{k}" if gpu is not None else args.work  # lanes never share a feature cache
    out = args.work / f"{stamp}.json"
    out.unlink(missing_ok=True)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", str(out), "--",
           *ns_train_args(name, args.data, ds, args.steps, work, stamp, args.vis)]
    env = dict(os.environ)
    if args.stop_after_s:
        env["BENCH_NS_TRAIN_DEADLINE"] = str(time.time() + args.stop_after_s)
    preexec = None
    if gpu is not None:
        env["CUDA_VISIBLE_DEVICES"] = gpu
        env["OMP_NUM_THREADS"] = str(len(cpus))
        preexec = lambda: os.sched_setaffinity(0, cpus)  # noqa: E731
    t0 = time.perf_counter()
    err = None
    with open(logs / f"{stamp}.log", "w") as log:
        try:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, timeout=args.timeout, env=env,
                                preexec_fn=preexec).returncode
            err = None if rc == 0 else f"exit {rc}"
        except subprocess.TimeoutExpired:
            err = f"timeout {args.timeout:.0f}s"
    result = json.loads(out.read_text()) if out.is_file() else {}
    if result.get("stopped_at_step") is not None:
        err = f"stopped at step {result['stopped_at_step']} (--stop-after-s {args.stop_after_s:.0f})"
    return {"name": name, "downscale": ds, "repeat": rep, "lane": k, "gpu": gpu, "result": result, "error": err,
            "stats": window_stats(result, lo, hi), "t_start": t0, "process_s": time.perf_counter() - t0}


def ratio_window(steps: int) -> int:
    """Width of the per-window ratio columns: 500 steps up to 3000, else about six columns of whole 500s."""
    return 500 if steps <= 3000 else max(500, round(steps / 6 / 500) * 500)


def summary(rows: List[dict]) -> List[str]:
    """Per variant and downscale over its repeats: the ratio to splatfacto's median step time (same downscale and
    repeat), memory ratio and PSNR / SSIM difference, as median [min, max]."""
    base = {(r["downscale"], r["repeat"]): r for r in rows if r["name"] == "splatfacto" and r["stats"].get("n")}
    cells: Dict[tuple, List[tuple]] = {}
    for r in rows:
        b = base.get((r["downscale"], r["repeat"]))
        if r["name"] == "splatfacto" or not b or not r["stats"].get("n"):
            continue
        ev, evb = r["result"].get("eval", {}), b["result"].get("eval", {})
        cells.setdefault((r["name"], r["downscale"]), []).append((
            r["stats"]["median"] / b["stats"]["median"],
            r["result"].get("peak_mem_mib", float("nan")) / b["result"].get("peak_mem_mib", float("nan")),
            ev.get("psnr", float("nan")) - evb.get("psnr", float("nan")),
            ev.get("ssim", float("nan")) - evb.get("ssim", float("nan"))))

    def fmt(xs: List[float], f: str) -> str:
        xs = [x for x in xs if x == x]
        return f"{statistics.median(xs):{f}} [{min(xs):{f}}, {max(xs):{f}}]" if xs else "n/a"

    out = ["| run | ds | pairs | x splatfacto step (median) | x peak memory | PSNR difference dB | SSIM difference |",
           "|---|---|---|---|---|---|---|"]
    for (name, ds), v in sorted(cells.items(), key=lambda kv: (-kv[0][1], kv[0][0])):
        out.append(f"| {name} | {ds} | {len(v)} | {fmt([x[0] for x in v], '.3f')} | {fmt([x[1] for x in v], '.2f')} | "
                   f"{fmt([x[2] for x in v], '+.2f')} | {fmt([x[3] for x in v], '+.4f')} |")
    return out


def main(argv: Optional[Sequence[str]] = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "--child":
        sep = argv.index("--")
        return child(Path(argv[1]), argv[sep + 1:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="nerfstudio dataset (e.g. ../shared/data/fox)")
    ap.add_argument("--runs", default="splatfacto@4,cinesplat@4,splatfacto@2,cinesplat@2",
                    help="NAME@DOWNSCALE in run order (interleave methods); names: " + ", ".join(VARIANTS))
    ap.add_argument("--steps", type=int, default=3000, help="--max-num-iterations of every run")
    ap.add_argument("--repeats", type=int, default=1, help="cycle through --runs this many times")
    ap.add_argument("--window", default="1000:3000", help="steps lo:hi the statistics use")
    ap.add_argument("--vis", default="viewer", help="ns-train --vis (default: nerfstudio's default, the viewer)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_ns_train"))
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per run before it is killed")
    ap.add_argument("--budget-s", type=float, default=None,
                    help="start no run that would end after this many seconds, judged by the longest run so far "
                         "(a device command's time limit)")
    ap.add_argument("--logs", type=Path, default=None, help="folder for each run's console log (default: --work)")
    ap.add_argument("--out-json", type=Path, default=None, help="all results (per-step times included) as JSON")
    ap.add_argument("--record", default=str(REPO / "benchmarks" / "RESULTS.md"),
                    help="markdown file the result section is appended to ('none': print only)")
    ap.add_argument("--stop-after-s", type=float, default=None,
                    help="end a run's training after this many seconds from its start, then measure and evaluate it "
                         "as after its last step (a long schedule cut to fit a device command; the table says where)")
    ap.add_argument("--gpus", default=None,
                    help="comma-separated GPU indices: one lane per GPU, runs in parallel, each on its GPU and an "
                         "equal slice of the host's cores (default: one lane, the visible GPU)")
    ap.add_argument("--layout", choices=("latin", "deal"), default="latin",
                    help="with --gpus: 'latin' (every lane runs the whole list, rotated) or 'deal' (the list dealt "
                         "out)")
    args = ap.parse_args(argv)
    if args.gpus is not None:  # before any run: a bad list would otherwise fail every child in turn
        ids = [g.strip() for g in args.gpus.split(",")]
        if not all(g.isdigit() for g in ids) or len(set(ids)) != len(ids):
            ap.error(f"--gpus: comma-separated GPU indices (0, 1, ...), each once; got {args.gpus!r}")
    if args.stop_after_s is not None and not args.stop_after_s > 0:
        ap.error(f"--stop-after-s: seconds > 0; got {args.stop_after_s}")
    lo, hi = (int(x) for x in args.window.split(":"))
    runs = parse_runs(args.runs)
    gpus = [g.strip() for g in args.gpus.split(",")] if args.gpus else [None]
    queues = lane_queues(runs, args.repeats, len(gpus), args.layout)
    args.work.mkdir(parents=True, exist_ok=True)
    logs = args.logs or args.work
    logs.mkdir(parents=True, exist_ok=True)
    date = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    rows: List[dict] = []
    skipped: List[str] = []
    t_bench = time.perf_counter()
    lock = threading.Lock()
    cpu_slices = cpu_split(len(gpus)) if args.gpus else [None]

    def lane(k: int) -> None:
        longest = 0.0
        for name, ds, rep in queues[k]:
            stamp = f"{name}_ds{ds}_r{rep}"
            # a run longer than any so far (in this lane) would not end inside the budget: skip it, so the table is
            # still printed
            if args.budget_s is not None and time.perf_counter() - t_bench + longest > args.budget_s:
                with lock:
                    skipped.append(stamp)
                continue
            row = run_one(name, ds, rep, k, gpus[k], cpu_slices[k], args, logs, lo, hi)
            longest = max(longest, row["process_s"])
            with lock:
                rows.append(row)
                st, result = row["stats"], row["result"]
                print(f"[{stamp} gpu {gpus[k]}] {row['error'] or 'ok'} in {row['process_s']:.0f}s: "
                      + (f"median {st['median']:.2f} ms p95 {st['p95']:.2f} max {st['max']:.1f} mean {st['mean']:.2f} "
                         f"console {st['console_median']:.2f}; Gaussians {result.get('gaussians')}; "
                         f"peak {result.get('peak_mem_mib', float('nan')):.0f} MiB; eval {result.get('eval')}"
                         if st.get("n") else "no steps recorded"), flush=True)
                if args.out_json:
                    _write_json(args.out_json, {"date": date, "rows": rows})

    threads = [threading.Thread(target=lane, args=(k,)) for k in range(len(gpus))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    rows.sort(key=lambda r: (r["repeat"], r["lane"], r["t_start"]))
    if skipped:
        print(f"not run (--budget-s {args.budget_s:.0f} spent): {', '.join(skipped)}", flush=True)
    device = next((r["result"].get("device") for r in rows if r["result"].get("device")), "?")
    lines = [
        f"### bench_ns_train.py  {date}  {device}",
        "",
        f"`bench_ns_train.py --data {args.data.name} --runs {args.runs} --steps {args.steps} "
        f"--repeats {args.repeats}" + (f" --gpus {args.gpus} --layout {args.layout}" if args.gpus else "") + "`: "
        f"stock `ns-train` processes in this order, nerfstudio's own step timer (\"Train Iter (time)\", host time, "
        f"not CUDA-synced) over steps {lo}-{hi}; console median = median of the 20-step running mean the console "
        "prints; peak MiB = max_memory_allocated of the training steps (setup peak: before step 0); eval over the eval "
        "split after the last step.",
        "",
        *table(rows, lo, hi),
        "",
        "Over the repeats (median [min, max] of the per-repeat ratios / differences to splatfacto):",
        "",
        *summary(rows),
        "",
        "x splatfacto (median step time) per step window:",
        "",
        *window_ratios(rows, list(range(0, args.steps, ratio_window(args.steps))) + [args.steps]),
        "",
    ]
    text = "\n".join(lines)
    print("\n" + text)
    if args.record.lower() != "none":
        with open(args.record, "a") as f:
            f.write("\n" + text + "\n")
        print(f"appended to {args.record}")


if __name__ == "__main__":
    main()
