#!/usr/bin/env python3
"""cinesplat benchmark (GPU): training step time and PSNR vs splatfacto, CLIP extraction, codec, relevancy.

    python benchmarks/bench_method.py --fox ../shared/data/fox [--steps 2000] [--downscale 2]
        [--modes splatfacto,cinesplat,cinesplat-every2,cinesplat-fused,cinesplat-image] [--clip-random-weights]
        [--no-record]

Training runs in-process with nerfstudio's own pipeline / optimizers / callbacks, the loop of
``Trainer.train_iteration`` without eval, saving or viewer. Every mode starts from the same seeds.
* step time: median and mean of per-step wall times (CUDA-synchronised) over steps >= 50.
* PSNR: mean over the eval split (nerfstudio's default 90/10 split) after the last step, full resolution.
Targets (issue 4): cinesplat step time <= 1.3x splatfacto's; PSNR within 0.3 dB; relevancy 1M <= 10 ms.
Results: printed as a table and appended to benchmarks/RESULTS.md with date and device.
"""

from __future__ import annotations

import argparse
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
    for step in range(args.steps):
        _sync()
        ts = time.perf_counter()
        for cb in callbacks:
            cb.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        optimizers.zero_grad_all()
        _, loss_dict, _ = pipeline.get_train_loss_dict(step=step)
        loss = functools.reduce(torch.add, loss_dict.values())
        loss.backward()
        optimizers.optimizer_step_all()
        optimizers.scheduler_step_all(step)
        for cb in callbacks:
            cb.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
        _sync()
        times.append(time.perf_counter() - ts)
    # eval PSNR
    pipeline.eval()
    model = pipeline.model
    psnrs = []
    with torch.no_grad():
        for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
            out = model.get_outputs_for_camera(camera)
            gt = model.composite_with_background(model.get_gt_img(batch["image"]), out["background"])
            psnrs.append(float(model.psnr(out["rgb"], gt)))
    res = {
        "mode": mode,
        "steps": args.steps,
        "setup_s": setup_s,
        "step_ms_median": 1000 * statistics.median(times[50:] or times),
        "step_ms_mean": 1000 * statistics.fmean(times[50:] or times),
        "psnr": statistics.fmean(psnrs),
        "n_eval": len(psnrs),
        "gaussians": int(model.num_points),
    }
    stats = getattr(pipeline.datamanager, "semantic_stats", None)
    if stats:
        res["codec_s"] = stats.get("seconds")
        res["feature_s"] = stats.get("feature_seconds")
        res["feature_cache_hit"] = stats.get("cache_hit")
        res["codec_1mcos"] = stats.get("error_after")
    del pipeline, optimizers, model
    torch.cuda.empty_cache()
    return res


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
    ap.add_argument("--modes", default="splatfacto,cinesplat,cinesplat-every2,cinesplat-fused,cinesplat-image")
    ap.add_argument("--clip-random-weights", action="store_true",
                    help="no CLIP weights on this machine: random (same speed)")
    ap.add_argument("--clip-images", type=int, default=50)
    ap.add_argument("--skip", default="", help="comma list of: train,clip,codec,relevancy")
    ap.add_argument("--no-record", action="store_true", help="do not append to benchmarks/RESULTS.md")
    args = ap.parse_args()
    if not torch.cuda.is_available():
        sys.exit("bench_method.py needs a CUDA GPU (gsplat)")
    args.work.mkdir(parents=True, exist_ok=True)
    skip = set(filter(None, args.skip.split(",")))
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
        "50 (CUDA-synced)",
        "",
        "| mode | step ms (median) | step ms (mean) | x splatfacto | PSNR (eval) | dPSNR | Gaussians | setup s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        ratio = r["step_ms_median"] / base["step_ms_median"] if base else float("nan")
        dpsnr = r["psnr"] - base["psnr"] if base else float("nan")
        lines.append(
            f"| {r['mode']} | {r['step_ms_median']:.2f} | {r['step_ms_mean']:.2f} | {ratio:.3f} | {r['psnr']:.2f} | "
            f"{dpsnr:+.2f} | {r['gaussians']} | {r['setup_s']:.1f} |"
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
