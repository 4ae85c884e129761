#!/usr/bin/env python3
"""cinesplat benchmark (GPU): training step time and PSNR vs splatfacto, CLIP extraction, codec, relevancy.

    python benchmarks/bench_method.py --fox ../shared/data/fox [--steps 2000] [--downscale 2]
        [--modes splatfacto,cinesplat,cinesplat-every2,cinesplat-fused,cinesplat-image] [--clip-random-weights]
        [--no-record]

Training runs in-process with nerfstudio's own pipeline / optimizers / callbacks, the loop of
``Trainer.train_iteration`` without eval, saving or viewer. Every mode starts from the same seeds.
* step time: median and mean of per-step host wall times over steps >= --window-start (default 50), taken like
  nerfstudio's TimeWriter (no CUDA sync per step, so queued GPU work is paid at the next host sync, as in ns-train);
  ``--sync-steps``: CUDA-synchronised before and after every step (the timer of this script before issue 36).
  What the user sees is benchmarks/bench_ns_train.py (stock ns-train processes); RESULTS.md compares the two.
* ``--profile-at S --profile-steps N``: after step S, N steps under torch.profiler with named regions (RGB pass,
  latent pass, loss, backward, optimizer, callbacks) and N more with CUDA sync debugging on, counting host
  synchronisations per step by source line; tables printed and written to --profile-out.
* PSNR: mean over the eval split (nerfstudio's default 90/10 split) after the last step, full resolution.
The loop's step times are diagnostic: they differ from ns-train's by more than 3% (RESULTS.md, issue 36), so the
training-speed number of record is bench_ns_train.py's; this script is kept to drive the profiler and for the
CLIP, codec and relevancy timings.
Results: printed as a table and appended to benchmarks/RESULTS.md with date and device.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import datetime as dt
import functools
import json
import random
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _sync():
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def _seed(s=0):
    random.seed(s)
    np.random.seed(s)
    torch.manual_seed(s)
    torch.cuda.manual_seed_all(s)


def make_config(mode: str, fox: Path, steps: int, downscale: int, work: Path, random_weights: bool):
    from nerfstudio.configs.method_configs import method_configs
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    from cinenerf_ns.method.cinesplat_config import make_cinesplat_config

    if mode == "splatfacto":
        cfg = copy.deepcopy(method_configs["splatfacto"])
    else:
        cfg = make_cinesplat_config()
        dm = cfg.pipeline.datamanager
        dm.clip.random_weights = random_weights
        dm.feature_cache_dir = work / "feature_cache"
        m = cfg.pipeline.model
        if mode == "cinesplat-image":
            m.latent_render_resolution = "image"
        elif mode == "cinesplat-separate":
            m.latent_render_mode = "separate"
        elif mode == "cinesplat-feature":
            m.latent_render_mode, m.latent_render_resolution = "separate", "feature"
        elif mode == "cinesplat-fused":
            m.latent_render_mode = "fused"
        elif mode == "cinesplat-every2":
            m.latent_every = 2
        elif mode != "cinesplat":
            raise ValueError(mode)
    cfg.max_num_iterations = steps
    cfg.pipeline.datamanager.data = fox
    dp = cfg.pipeline.datamanager.dataparser
    assert isinstance(dp, NerfstudioDataParserConfig)
    dp.data = fox
    dp.downscale_factor = downscale
    return cfg


def train(mode: str, args) -> dict:
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation
    from nerfstudio.engine.optimizers import Optimizers
    from nerfstudio.models.splatfacto import SplatfactoModel

    from cinenerf_ns.method.compat import offline_safe_lpips
    from cinenerf_ns.method.model import CineSplatModel

    cfg = make_config(mode, args.fox, args.steps, args.downscale, args.work, args.clip_random_weights)
    _seed(0)
    # the baseline gets the same offline fixes as cinesplat (LPIPS stand-in, kNN without scikit-learn);
    # neither changes what is trained
    orig_knn = SplatfactoModel.k_nearest_sklearn
    SplatfactoModel.k_nearest_sklearn = CineSplatModel.k_nearest_sklearn
    t0 = time.perf_counter()
    try:
        with offline_safe_lpips("cached"):
            pipeline = cfg.pipeline.setup(device="cuda", test_mode="val", world_size=1, local_rank=0, grad_scaler=None)
    finally:
        SplatfactoModel.k_nearest_sklearn = orig_knn
    setup_s = time.perf_counter() - t0
    optimizers = Optimizers(cfg.optimizers.copy(), pipeline.get_param_groups())
    scaler = torch.amp.GradScaler("cuda", enabled=False)
    callbacks = pipeline.get_training_callbacks(
        TrainingCallbackAttributes(optimizers=optimizers, grad_scaler=scaler, pipeline=pipeline, trainer=None)
    )
    pipeline.train()
    times = []

    def one_step(step, region=None):
        region = region or (lambda name: contextlib.nullcontext())
        with region("callbacks_before"):
            for cb in callbacks:
                cb.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        optimizers.zero_grad_all()
        with region("forward_and_loss"):
            _, loss_dict, _ = pipeline.get_train_loss_dict(step=step)
            loss = functools.reduce(torch.add, loss_dict.values())
        with region("backward"):
            loss.backward()
        with region("optimizer_step"):
            optimizers.optimizer_step_all()
            optimizers.scheduler_step_all(step)
        with region("callbacks_after (densification)"):
            for cb in callbacks:
                cb.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)

    step = 0
    while step < args.steps:
        if args.profile_at is not None and step == args.profile_at:
            try:
                profile_steps(mode, pipeline, one_step, step, args)
            except Exception:  # diagnostics must not cost the timing run
                import traceback

                traceback.print_exc()
                torch.cuda.set_sync_debug_mode("default")
            step += 2 * args.profile_steps
            continue
        if args.sync_steps:
            _sync()
        ts = time.perf_counter()
        one_step(step)
        if args.sync_steps:
            _sync()
        times.append(time.perf_counter() - ts)
        step += 1
    model = pipeline.model
    _sync()
    w = args.window_start
    res = {
        "mode": mode,
        "steps": args.steps,
        "setup_s": setup_s,
        "step_ms_median": 1000 * statistics.median(times[w:] or times),
        "step_ms_mean": 1000 * statistics.fmean(times[w:] or times),
        "psnr": float("nan"),
        "n_eval": 0,
        "gaussians": int(model.num_points),
        "peak_mem_mib": torch.cuda.max_memory_allocated() / 2**20,
    }
    if "eval" not in args.skip_set:  # eval PSNR
        pipeline.eval()
        psnrs = []
        with torch.no_grad():
            for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
                out = model.get_outputs_for_camera(camera)
                gt = model.composite_with_background(model.get_gt_img(batch["image"]), out["background"])
                psnrs.append(float(model.psnr(out["rgb"], gt)))
        res["psnr"], res["n_eval"] = statistics.fmean(psnrs), len(psnrs)
    stats = getattr(pipeline.datamanager, "semantic_stats", None)
    if stats:
        res["codec_s"] = stats.get("seconds")
        res["feature_s"] = stats.get("feature_seconds")
        res["feature_cache_hit"] = stats.get("cache_hit")
        res["codec_1mcos"] = stats.get("error_after")
    pipeline = optimizers = model = None  # free the GPU memory before the next mode (one_step holds cells)
    torch.cuda.empty_cache()
    torch.cuda.reset_peak_memory_stats()
    return res


# model methods timed as named regions while profiling (class, attribute, label)
PROFILED_METHODS = [
    ("nerfstudio.models.splatfacto:SplatfactoModel", "get_outputs", "rgb_pass (splatfacto.get_outputs)"),
    ("cinenerf_ns.method.model:CineSplatModel", "_shared_latents", "latent_pass shared (rasterize_to_pixels)"),
    ("cinenerf_ns.method.model:CineSplatModel", "render_latents", "latent_pass separate (gsplat rasterization)"),
    ("cinenerf_ns.method.model:CineSplatModel", "_get_outputs_fused", "fused_pass (RGB + latent, 6 channels)"),
    ("nerfstudio.models.splatfacto:SplatfactoModel", "get_loss_dict", "rgb_loss (splatfacto.get_loss_dict)"),
    ("nerfstudio.models.splatfacto:SplatfactoModel", "get_metrics_dict", "metrics (psnr, count)"),
    ("nerfstudio.data.datamanagers.full_images_datamanager:FullImageDatamanager", "next_train",
     "next_train (datamanager)"),
]


@contextlib.contextmanager
def _method_regions():
    """Wrap PROFILED_METHODS in torch.profiler.record_function for the duration of the block."""
    import importlib

    from torch.profiler import record_function

    saved = []
    for spec, attr, label in PROFILED_METHODS:
        mod, cls_name = spec.split(":")
        cls = getattr(importlib.import_module(mod), cls_name)
        orig = cls.__dict__.get(attr)
        if orig is None:
            continue

        def wrapped(*a, __orig=orig, __label=label, **k):
            with record_function(__label):
                return __orig(*a, **k)

        setattr(cls, attr, wrapped)
        saved.append((cls, attr, orig))
    try:
        yield
    finally:
        for cls, attr, orig in reversed(saved):
            setattr(cls, attr, orig)


def profile_steps(mode: str, pipeline, one_step, step0: int, args) -> None:
    """args.profile_steps steps under torch.profiler (named regions: CPU and CUDA time per step), then as many with
    CUDA sync debugging (host synchronisations per step, by source line). Prints and writes <profile_out>/<mode>.txt."""
    import collections
    import warnings

    from torch.profiler import ProfilerActivity, profile, record_function

    n = args.profile_steps
    lines = [f"## profile {mode}: steps {step0}-{step0 + n - 1}, {pipeline.model.num_points} Gaussians, "
             f"{torch.cuda.get_device_name(0)}"]
    region = lambda name: record_function("step/" + name)  # noqa: E731
    _sync()
    t0 = time.perf_counter()
    with _method_regions(), profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        for i in range(n):
            with record_function("step/total"):
                one_step(step0 + i, region)
        _sync()
    wall = (time.perf_counter() - t0) / n
    ka = prof.key_averages()
    dev = lambda e: getattr(e, "device_time_total", None) or getattr(e, "cuda_time_total", 0.0)  # noqa: E731
    labels = {lab for _, _, lab in PROFILED_METHODS}
    lines.append(f"wall per profiled step (profiler on, synced at the end): {1000 * wall:.2f} ms")
    lines.append("| region | calls/step | CPU ms/step (incl. children) | CUDA ms/step (kernels launched inside) |")
    lines.append("|---|---|---|---|")
    rows = [e for e in ka if e.key.startswith("step/") or e.key in labels]
    for e in sorted(rows, key=lambda e: -e.cpu_time_total):
        lines.append(f"| {e.key} | {e.count / n:.2f} | {e.cpu_time_total / 1000 / n:.3f} | {dev(e) / 1000 / n:.3f} |")
    # kernels only: the named regions (record_function) also appear with a device-side time; leave them out
    kern = [e for e in ka if getattr(e, "device_type", None) is not None and "CUDA" in str(e.device_type)
            and not e.key.startswith("step/") and e.key not in labels and not e.key.startswith("Optimizer.")
            and (getattr(e, "self_device_time_total", 0) or getattr(e, "self_cuda_time_total", 0))]
    tot_dev = sum(getattr(e, "self_device_time_total", 0) or getattr(e, "self_cuda_time_total", 0) for e in kern)
    lines.append(f"GPU kernel time per step (sum of all kernels): {tot_dev / 1000 / n:.3f} ms; kernels launched per "
                 f"step: {sum(e.count for e in kern) / n:.0f}")
    lines.append("| top kernels | calls/step | CUDA ms/step |")
    lines.append("|---|---|---|")
    for e in sorted(kern, key=lambda e: -(getattr(e, "self_device_time_total", 0) or e.self_cuda_time_total))[:15]:
        t = getattr(e, "self_device_time_total", 0) or e.self_cuda_time_total
        lines.append(f"| {e.key[:90]} | {e.count / n:.2f} | {t / 1000 / n:.3f} |")
    # host synchronisations: CUDA sync debug mode warns at every synchronising call
    syncs: collections.Counter = collections.Counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            torch.cuda.set_sync_debug_mode("warn")
            try:
                for i in range(n):
                    one_step(step0 + n + i)
            finally:
                torch.cuda.set_sync_debug_mode("default")
        for w in caught:
            if "synchroniz" in str(w.message).lower():
                syncs[f"{Path(w.filename).name}:{w.lineno}"] += 1
        lines.append(f"host synchronisations per step: {sum(syncs.values()) / n:.2f}")
        lines.append("| source line | per step |")
        lines.append("|---|---|")
        for k, c in syncs.most_common(20):
            lines.append(f"| {k} | {c / n:.2f} |")
    except Exception as e:  # pragma: no cover - diagnostics only
        lines.append(f"sync counting failed: {type(e).__name__}: {e}")
    text = "\n".join(lines) + "\n"
    print(text, flush=True)
    if args.profile_out:
        args.profile_out.mkdir(parents=True, exist_ok=True)
        (args.profile_out / f"profile_{mode}.txt").write_text(text)


def bench_clip(args) -> dict:
    """Dense CLIP features (default settings) on the fox train images at the benchmark downscale."""
    from PIL import Image

    from cinenerf_ns.method.clip_features import ClipFeatureConfig, DenseClipExtractor

    cfg = ClipFeatureConfig(random_weights=args.clip_random_weights)
    ext = DenseClipExtractor(cfg, "cuda")
    folder = args.fox / (f"images_{args.downscale}" if args.downscale > 1 else "images")
    files = sorted(folder.glob("*"))[: args.clip_images]
    imgs = [torch.from_numpy(np.array(Image.open(f).convert("RGB"))) for f in files]
    ext.extract(imgs[0])  # warm-up (cuDNN autotune, allocator)
    _sync()
    t0 = time.perf_counter()
    for im in imgs:
        ext.extract(im)
    _sync()
    secs = time.perf_counter() - t0
    return {
        "clip_model": f"{cfg.model_name}/{'random' if cfg.random_weights else cfg.pretrained}",
        "clip_images": len(imgs),
        "clip_img_per_s": len(imgs) / secs,
        "clip_hw": tuple(imgs[0].shape[:2]),
        "clip_scales": cfg.input_long_sides,
    }


def bench_codec(args) -> dict:
    from cinenerf_ns.method.codec import CodecConfig, train_codec

    g = torch.Generator().manual_seed(0)
    centers = torch.nn.functional.normalize(torch.randn(20, 512, generator=g), dim=-1)
    x = centers[torch.randint(0, 20, (200_000,), generator=g)] + 0.02 * torch.randn(200_000, 512, generator=g)
    _, st = train_codec(x, CodecConfig(), device="cuda", progress=False)
    return {"codec_train_s": st["seconds"], "codec_err": st["error_after"], "codec_backend": CodecConfig().backend}


def bench_relevancy(args, n=1_000_000, reps=30) -> dict:
    from cinenerf_ns.method.codec import CodecConfig, FeatureCodec
    from cinenerf_ns.method.relevancy import relevancy

    codec = FeatureCodec(512, CodecConfig(), device="cuda")
    lat = torch.rand(n, 3, device="cuda") * 2 - 1
    q = torch.randn(512, device="cuda")
    neg = torch.randn(4, 512, device="cuda")
    out = {}
    for fast in (True, False):
        for _ in range(3):
            relevancy(lat, codec, q, neg, fast=fast)
        ts = []
        for _ in range(reps):
            _sync()
            t0 = time.perf_counter()
            relevancy(lat, codec, q, neg, fast=fast)
            _sync()
            ts.append(time.perf_counter() - t0)
        out["relevancy_1M_ms" + ("" if fast else "_decode_path")] = 1000 * statistics.median(ts)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fox", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("/tmp/cinesplat_bench"))
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--downscale", type=int, default=2)
    ap.add_argument("--modes", default="splatfacto,cinesplat,cinesplat-separate,cinesplat-every2,cinesplat-fused")
    ap.add_argument("--clip-random-weights", action="store_true",
                    help="no CLIP weights on this machine: random (same speed)")
    ap.add_argument("--clip-images", type=int, default=50)
    ap.add_argument("--skip", default="", help="comma list of: train,eval,clip,codec,relevancy")
    ap.add_argument("--no-record", action="store_true", help="do not append to benchmarks/RESULTS.md")
    ap.add_argument("--sync-steps", action="store_true",
                    help="CUDA-synchronise before and after every timed step (default: host time like ns-train)")
    ap.add_argument("--window-start", type=int, default=50, help="step time statistics over steps >= this")
    ap.add_argument("--profile-at", type=int, default=None, help="profile the steps after this one")
    ap.add_argument("--profile-steps", type=int, default=30, help="steps profiled (and as many sync-counted)")
    ap.add_argument("--profile-out", type=Path, default=None, help="folder for profile_<mode>.txt")
    args = ap.parse_args()
    if not torch.cuda.is_available():
        sys.exit("bench_method.py needs a CUDA GPU (gsplat)")
    args.work.mkdir(parents=True, exist_ok=True)
    skip = set(filter(None, args.skip.split(",")))
    args.skip_set = skip
    device = torch.cuda.get_device_name(0)
    results: dict = {"date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "device": device,
                     "torch": torch.__version__}
    try:
        import gsplat

        results["gsplat"] = gsplat.__version__
    except Exception:
        pass
    runs = []
    if "train" not in skip:
        for mode in args.modes.split(","):
            r = train(mode.strip(), args)
            print(json.dumps(r), flush=True)
            runs.append(r)
    extra = {}
    if "clip" not in skip:
        extra.update(bench_clip(args))
    if "codec" not in skip:
        extra.update(bench_codec(args))
    if "relevancy" not in skip:
        extra.update(bench_relevancy(args))
    print(json.dumps(extra), flush=True)

    base = next((r for r in runs if r["mode"] == "splatfacto"), None)
    lines = [
        f"### bench_method.py  {results['date']}  {device}  torch {results['torch']}  gsplat "
        f"{results.get('gsplat', '?')}",
        "",
        f"fox, --downscale-factor {args.downscale}, {args.steps} steps, same seeds; step time = median over steps >= "
        f"{args.window_start} ("
        + ("CUDA-synced per step" if args.sync_steps else "host time per step, not synced, as ns-train") + ")",
        "",
        "Diagnostic only: the in-process loop is not what `ns-train` shows (it has no viewer, writer or eval images, "
        "and its default window starts at step 50, where cinesplat's gap is smallest); the training-speed number of "
        "record is benchmarks/bench_ns_train.py's.",
        "",
        "| mode | step ms (median) | step ms (mean) | x splatfacto (in-process) | PSNR (eval) | dPSNR | Gaussians "
        "| peak MiB | setup s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        ratio = r["step_ms_median"] / base["step_ms_median"] if base else float("nan")
        dpsnr = r["psnr"] - base["psnr"] if base else float("nan")
        lines.append(
            f"| {r['mode']} | {r['step_ms_median']:.2f} | {r['step_ms_mean']:.2f} | {ratio:.3f} | {r['psnr']:.2f} | "
            f"{dpsnr:+.2f} | {r['gaussians']} | {r.get('peak_mem_mib', float('nan')):.0f} | {r['setup_s']:.1f} |"
        )
    lines.append("")
    for k, v in extra.items():
        lines.append(f"- {k}: {v:.3f}" if isinstance(v, float) else f"- {k}: {v}")
    for r in runs:
        if "codec_s" in r:
            lines.append(
                f"- {r['mode']}: feature extraction {r.get('feature_s', 0):.1f}s (cache hit "
                f"{r.get('feature_cache_hit')}), "
                f"codec fit {r['codec_s']:.1f}s, codec 1-cos {r['codec_1mcos']:.4f}"
            )
    lines.append("")
    table = "\n".join(lines)
    print("\n" + table)
    if not args.no_record:
        with open(REPO / "benchmarks" / "RESULTS.md", "a") as f:
            f.write("\n" + table + "\n")
        print(f"appended to {REPO / 'benchmarks' / 'RESULTS.md'}")


if __name__ == "__main__":
    main()
