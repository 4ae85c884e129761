#!/usr/bin/env bash
# GPU check for cinenerf_ns on a CUDA machine with no network.
#
#   scripts/gpu_check.sh [STAGE...]
#   stages: install tests train render viewer labels bench   (default: install tests train render viewer labels)
#     install  wheels -> $SITE, dist-info with our entry points, import check
#     tests    gsplat CUDA compile (timed), then the whole pytest suite incl. GPU tests
#     train    ns-train cinesplat on a copy of fox, $STEPS steps, random-weight CLIP, no viewer; text query check
#     render   ns-render camera-path of that checkpoint (rgb + latent images)
#     viewer   ns-viewer loads that checkpoint (serves for up to 45 s, log checked), stopped by its PID
#     labels   fox with generated 3-class brightness label masks: ns-train cinesplat --feature-source labels
#     bench    benchmarks/bench_method.py (cinesplat vs splatfacto etc.; appends to benchmarks/RESULTS.md)
#     trainspeed  benchmarks/bench_ns_train.py: stock ns-train splatfacto / cinesplat processes, nerfstudio's own step
#              timer ($TS_RUNS, default splatfacto@4,cinesplat@4,splatfacto@2,cinesplat@2; $TS_STEPS, default 3000;
#              ~45-60 s a run); results in $OUT/ns_train.json and $OUT/ns_train_section.md (append it to RESULTS.md)
#     room     synthetic room (cinesplat-synth, seed $ROOM_SEED) -> ns-train cinesplat with label masks ($ROOM_STEPS
#              steps) -> compact export + ground-truth files in $OUT/room (the bundled demo scene's recipe)
#     planner  benchmarks/bench_planner.py, bench_candidates.py, bench_viewer.py on CUDA (1M Gaussians)
#     demo_render  cinesplat-plan from text on the room run, then stock ns-render of the planned camera path
#     gputests GPU-marked tests only (not slow); latency: bench_planner per family / start mode + bench_candidates
#     shots    720p GPU preview of the demo shot, preview-vs-gsplat tests, stock ns-render mp4 (needs imageio-ffmpeg)
#   render/viewer use RUN_CFG (a run's config.yml) and RUN_DATA (its dataset) when set, else the fox run
#
# Environment:
#   OUT        where logs, timings and rendered frames go (default ./gpu_check_out)
#   WHEELS     folder of wheels to install with --no-index (default .whl; skipped when absent)
#   FOX        the fox scene (default: first of $CINENERF_FOX, shared/data/fox, ../shared/data/fox)
#   STEPS      ns-train iterations (default 2000)
#   SITE       pip --target folder (default /tmp/site)
#   PYTEST_ARGS extra pytest arguments (e.g. "-x")
# Each stage appends "stage seconds rc" to $OUT/timings.txt; logs are $OUT/<stage>.log.
# Stages are idempotent and can be run in separate calls (each under 10 minutes): install is skipped
# when $SITE/.cinenerf_installed exists; render uses the newest training run under $WORK/outputs.
# gsplat compiles its CUDA kernels on first use (~80 s on an H100); the tests stage pays it first.
set -uo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
OUT=${OUT:-$REPO/gpu_check_out}
WHEELS=${WHEELS:-$REPO/.whl}
SITE=${SITE:-/tmp/site}
STEPS=${STEPS:-2000}
WORK=${WORK:-/tmp/cinesplat_gpu_check}
mkdir -p "$OUT" "$WORK"
PY=${PY:-python3}

if [ -z "${FOX:-}" ]; then
  for c in "${CINENERF_FOX:-}" "$REPO/shared/data/fox" "$REPO/../shared/data/fox" "/work/shared/data/fox"; do
    if [ -n "$c" ] && [ -f "$c/transforms.json" ]; then FOX=$c; break; fi
  done
fi

export PYTHONPATH=$REPO:$SITE${PYTHONPATH:+:$PYTHONPATH}
export PATH=$SITE/bin:$PATH
export CINENERF_FOX=${FOX:-}
export HF_HUB_OFFLINE=1   # no network: never wait on hub retries
export PYTHONUNBUFFERED=1

log() { echo "[gpu_check $(date -u +%H:%M:%S)] $*" | tee -a "$OUT/gpu_check.log"; }

run_stage() {  # run_stage NAME CMD...
  local name=$1; shift
  log "stage $name: $*"
  local t0=$(date +%s.%N)
  "$@" > "$OUT/$name.log" 2>&1
  local rc=$?
  local t1=$(date +%s.%N)
  local dt=$(echo "$t1 - $t0" | bc 2>/dev/null || $PY -c "print($t1-$t0)")
  echo "$name $dt $rc" >> "$OUT/timings.txt"
  log "stage $name: rc=$rc in ${dt}s (log: $OUT/$name.log)"
  tail -n 25 "$OUT/$name.log"
  return $rc
}

stage_install() {
  if [ -f "$SITE/.cinenerf_installed" ]; then log "install: already done ($SITE)"; return 0; fi
  mkdir -p "$SITE"
  if ls "$WHEELS"/*.whl > /dev/null 2>&1; then
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$WHEELS"/*.whl || return 1
  else
    log "install: no wheels in $WHEELS; using the machine's packages"
  fi
  # nerfstudio discovers methods through installed entry points: write a minimal dist-info for the repo
  # (the package itself is imported from $REPO through PYTHONPATH)
  $PY - "$SITE" "$REPO" <<'EOF' || return 1
import sys, pathlib
try:
    import tomllib
except ImportError:  # py < 3.11
    import tomli as tomllib
site, repo = map(pathlib.Path, sys.argv[1:3])
proj = tomllib.loads((repo / "pyproject.toml").read_text())["project"]
di = site / f"{proj['name']}-{proj['version']}.dist-info"
di.mkdir(parents=True, exist_ok=True)
(di / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {proj['name']}\nVersion: {proj['version']}\n")
lines = []
for group, eps in [("console_scripts", proj.get("scripts", {}))] + list(proj.get("entry-points", {}).items()):
    lines.append(f"[{group}]")
    lines += [f"{k} = {v}" for k, v in eps.items()]
    lines.append("")
(di / "entry_points.txt").write_text("\n".join(lines))
(di / "RECORD").write_text("")
print("wrote", di)
# console scripts (cinesplat-plan, cinesplat-preview, ffmpeg, ...) as pip would write them
bin_dir = site / "bin"
bin_dir.mkdir(exist_ok=True)
for name, target in proj.get("scripts", {}).items():
    mod, fn = target.split(":")
    exe = bin_dir / name
    exe.write_text(f"#!{sys.executable}\nimport sys\nfrom {mod} import {fn}\nsys.exit({fn}())\n")
    exe.chmod(0o755)
print("console scripts:", sorted(proj.get("scripts", {})))
EOF
  $PY - <<'EOF' || return 1
import importlib, sys
core = ["torch", "nerfstudio", "gsplat", "viser", "open_clip", "scipy", "cinenerf_ns.method"]
extra = ["pytest", "hypothesis", "cvxpy", "osqp", "clarabel", "tensorboard", "plyfile", "tinycudann"]  # tests / planner / optional
missing = []
for m in core + extra:
    try:
        importlib.import_module(m)
    except Exception as e:
        if m in core:
            missing.append(f"{m} ({type(e).__name__}: {e})")
        else:
            print(f"not available (optional for this stage set): {m} ({type(e).__name__})")
import torch
print("torch", torch.__version__, "cuda", torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else "-")
from importlib.metadata import entry_points
print("nerfstudio methods from plugins:", sorted(e.name for e in entry_points(group="nerfstudio.method_configs")))
if missing:
    print("MISSING core packages:", *missing, sep="\n  ")
    sys.exit(1)
EOF
  touch "$SITE/.cinenerf_installed"
}

gsplat_compile() {
  # first touch of gsplat compiles its CUDA kernels (~80 s). Under a lock: two stages that start it at once on a
  # fresh machine (two rooms in parallel) share torch's build folder, and one deletes it under the other.
  local lock=""
  command -v flock > /dev/null && lock="flock /tmp/cinenerf_gsplat_build.lock"
  $lock $PY -c "
import torch, time
from gsplat.rendering import rasterization
t=time.time()
m=torch.zeros(1,3,device='cuda'); m[0,2]=2
r,a,_=rasterization(m, torch.tensor([[1.,0,0,0]],device='cuda'), torch.full((1,3),.1,device='cuda'), torch.ones(1,device='cuda'), torch.ones(1,3,device='cuda'), torch.eye(4,device='cuda')[None], torch.tensor([[[10.,0,4],[0,10,4],[0,0,1]]],device='cuda'), 8, 8)
torch.cuda.synchronize(); print('gsplat first call (compile) %.1fs' % (time.time()-t))
"
}

stage_tests() {
  # first touch of gsplat compiles its CUDA kernels: do it visibly, timed on its own
  local t0=$(date +%s)
  gsplat_compile || return 1
  echo "gsplat_compile $(( $(date +%s) - t0 )) 0" >> "$OUT/timings.txt"
  $PY -c "import pytest, hypothesis" || { echo "pytest / hypothesis missing: add their wheels (pytest pluggy iniconfig packaging hypothesis sortedcontainers attrs) to $WHEELS"; return 1; }
  $PY -m pytest -q -ra ${PYTEST_ARGS:-} --junitxml="$OUT/pytest.xml"
}

stage_train() {
  [ -n "${FOX:-}" ] || { echo "fox scene not found: set FOX=/path/to/fox"; return 1; }
  # a copy (labels / caches never touch the shared scene); cp -a keeps mtimes so the feature cache key is stable
  [ -f "$WORK/fox/transforms.json" ] || cp -a "$FOX" "$WORK/fox"
  rm -rf "$WORK/outputs/fox/cinesplat/gpu_check"
  local vis=viewer
  $PY -c "import tensorboard" 2>/dev/null && vis=tensorboard
  ns-train cinesplat \
    --data "$WORK/fox" \
    --output-dir "$WORK/outputs" --experiment-name fox --timestamp gpu_check \
    --max-num-iterations "$STEPS" --steps-per-save "$STEPS" --steps-per-eval-all-images 100000 \
    --vis "$vis" --viewer.quit-on-train-completion True \
    --pipeline.datamanager.clip.random-weights True \
    nerfstudio-data --downscale-factor 4 || return 1
  local cfg="$WORK/outputs/fox/cinesplat/gpu_check/config.yml"
  ls -la "$(dirname "$cfg")/nerfstudio_models" || return 1
  grep -E "feature cache|latent targets|codec" "$OUT/train.log" | head -5
  query_check "$cfg" "fox"
}

query_check() {  # query_check CONFIG TEXT: trainer-free loading + a text query (relevancy stats, timing)
  $PY - "$1" "$2" <<'EOF'
import sys, time, torch
from cinenerf_ns.method.checkpoint import load_splat
from cinenerf_ns.method.relevancy import QueryError
from cinenerf_ns.method.semantic_scene import SemanticScene
st = load_splat(sys.argv[1])
lat = st.params.latents
print("checkpoint", st.path, "gaussians", len(st), "latents", None if lat is None else tuple(lat.shape),
      "latent std", None if lat is None else float(lat.std()), "codec", st.codec is not None, "step", st.step)
s = SemanticScene.from_checkpoint(sys.argv[1], device="cuda")
rel = s.query(sys.argv[2]); torch.cuda.synchronize()
t = time.perf_counter(); rel = s.query(sys.argv[2]); torch.cuda.synchronize()
print(f"query {sys.argv[2]!r}: relevancy min {float(rel.min()):.3f} mean {float(rel.mean()):.3f} max {float(rel.max()):.3f} "
      f"({1000*(time.perf_counter()-t):.2f} ms for {len(s)} Gaussians)")
try:
    c, mask = s.locate(sys.argv[2]); print("locate: centroid", [round(v, 3) for v in c.tolist()], "mask", int(mask.sum()))
except QueryError as e:
    print("locate:", e)
EOF
}

stage_render() {
  local cfg="${RUN_CFG:-$WORK/outputs/fox/cinesplat/gpu_check/config.yml}"
  local tr="${RUN_DATA:-$WORK/fox}/transforms.json"
  [ -f "$cfg" ] || { echo "no trained run at $cfg (run the train stage first)"; return 1; }
  # a camera path through 24 of the training poses, in the dataparser's normalised coordinates
  $PY - "$tr" "$(dirname "$cfg")/dataparser_transforms.json" "$WORK/camera_path.json" <<'EOF' || return 1
import json, sys, math
import numpy as np
tr, dp, out = sys.argv[1:4]
meta = json.load(open(tr)); d = json.load(open(dp))
T = np.eye(4); T[:3] = np.array(d["transform"]); s = d["scale"]
frames = sorted(meta["frames"], key=lambda f: f["file_path"])[:24]
H, W = 480, 270
fovy = 2 * math.degrees(math.atan(0.5 * meta["h"] / meta["fl_y"]))
path = []
for f in frames:
    c2w = T @ np.array(f["transform_matrix"]); c2w[:3, 3] *= s
    path.append({"camera_to_world": c2w.reshape(-1).tolist(), "fov": fovy, "aspect": W / H})
json.dump({"camera_type": "perspective", "render_height": H, "render_width": W, "camera_path": path,
           "fps": 24, "seconds": len(path) / 24, "smoothness_value": 0, "is_cycle": False, "crop": None}, open(out, "w"))
print("camera path", out, len(path), "frames")
EOF
  rm -rf "$OUT/render"
  # ns-render checks that ffmpeg exists even for --output-format images (it never runs it then). The
  # offline GPU machine has no ffmpeg, so put a stub on PATH that fails loudly if it is ever called.
  if ! command -v ffmpeg > /dev/null; then
    mkdir -p "$WORK/bin"
    printf '#!/bin/sh\necho "ffmpeg stub (gpu_check.sh): real ffmpeg is not installed on this machine" >&2\nexit 1\n' > "$WORK/bin/ffmpeg"
    chmod +x "$WORK/bin/ffmpeg"
    export PATH="$WORK/bin:$PATH"
  fi
  ns-render camera-path --load-config "$cfg" --camera-path-filename "$WORK/camera_path.json" \
    --output-path "$OUT/render" --output-format images --rendered-output-names rgb latent || return 1
  ls "$OUT/render" | head; ls "$OUT/render" | wc -l
}

stage_viewer() {
  local cfg="${RUN_CFG:-$WORK/outputs/fox/cinesplat/gpu_check/config.yml}"
  [ -f "$cfg" ] || { echo "no trained run at $cfg (run the train stage first)"; return 1; }
  ns-viewer --load-config "$cfg" --viewer.websocket-port 7123 > "$OUT/viewer_server.log" 2>&1 &
  local pid=$!
  local ok=1
  for _ in $(seq 1 45); do
    sleep 1
    kill -0 $pid 2>/dev/null || break
    if grep -q "Done loading checkpoint" "$OUT/viewer_server.log"; then ok=0; sleep 10; break; fi
  done
  kill $pid 2>/dev/null; wait $pid 2>/dev/null
  tail -n 30 "$OUT/viewer_server.log"
  grep -q "Traceback" "$OUT/viewer_server.log" && ok=1
  return $ok
}

stage_labels() {
  [ -n "${FOX:-}" ] || { echo "fox scene not found: set FOX=/path/to/fox"; return 1; }
  local d="$WORK/fox_labels"
  [ -f "$d/transforms.json" ] || cp -a "$FOX" "$d"
  # 3 classes by brightness tercile of each image (any integer masks exercise the label pipeline)
  $PY - "$d" <<'EOF' || return 1
import json, sys, pathlib
import numpy as np
from PIL import Image
d = pathlib.Path(sys.argv[1]); (d / "labels").mkdir(exist_ok=True)
for f in sorted((d / "images").glob("*")):
    out = d / "labels" / (f.stem + ".png")
    if out.exists():
        continue
    g = np.asarray(Image.open(f).convert("L"), dtype=np.float32)
    q = np.quantile(g, [1 / 3, 2 / 3])
    Image.fromarray(np.digitize(g, q).astype(np.uint8)).save(out)
(d / "labels.json").write_text(json.dumps({"0": "dark shadow", "1": "grey wall", "2": "bright light"}))
print("labels in", d / "labels", len(list((d / "labels").glob("*.png"))))
EOF
  rm -rf "$WORK/outputs/fox_labels/cinesplat/gpu_check"
  local vis=viewer
  $PY -c "import tensorboard" 2>/dev/null && vis=tensorboard
  ns-train cinesplat --data "$d" \
    --output-dir "$WORK/outputs" --experiment-name fox_labels --timestamp gpu_check \
    --max-num-iterations "${LABEL_STEPS:-500}" --steps-per-save "${LABEL_STEPS:-500}" --steps-per-eval-all-images 100000 \
    --vis "$vis" --viewer.quit-on-train-completion True \
    --pipeline.datamanager.feature-source labels --pipeline.datamanager.clip.random-weights True \
    nerfstudio-data --downscale-factor 4 || return 1
  query_check "$WORK/outputs/fox_labels/cinesplat/gpu_check/config.yml" "bright light"
}

stage_bench() {
  [ -n "${FOX:-}" ] || { echo "fox scene not found: set FOX=/path/to/fox"; return 1; }
  $PY benchmarks/bench_method.py --fox "$FOX" --work "$WORK/bench" --clip-random-weights
}

stage_trainspeed() {
  [ -n "${FOX:-}" ] || { echo "fox scene not found: set FOX=/path/to/fox"; return 1; }
  $PY benchmarks/bench_ns_train.py --data "$FOX" --runs "${TS_RUNS:-splatfacto@4,cinesplat@4,splatfacto@2,cinesplat@2}" \
    --steps "${TS_STEPS:-3000}" --work "$WORK/ns_train" --logs "$WORK/ns_train/logs" --out-json "$OUT/ns_train.json" \
    --record "$OUT/ns_train_section.md"
}

stage_room() {
  local d="$WORK/room${ROOM_SEED:-0}" steps=${ROOM_STEPS:-5000} name="room${ROOM_SEED:-0}"
  [ -f "$d/transforms.json" ] || $PY -c "from cinenerf_ns.synthetic.cli import entrypoint; entrypoint()" --seed "${ROOM_SEED:-0}" --num-views 150 --output "$d" \
      --threads "${ROOM_THREADS:-8}" --ply-in-transforms || return 1
  rm -rf "$WORK/outputs/$name/cinesplat/gpu_check"
  gsplat_compile || return 1  # seed 3 failed here once, compiled by two rooms at once (2026-11-25)
  ns-train cinesplat --data "$d" \
    --output-dir "$WORK/outputs" --experiment-name "$name" --timestamp gpu_check \
    --max-num-iterations "$steps" --steps-per-save "$steps" --steps-per-eval-all-images 100000 \
    --vis tensorboard --viewer.quit-on-train-completion True \
    --pipeline.datamanager.feature-source labels --pipeline.datamanager.clip.random-weights True \
    --pipeline.datamanager.clip.feature-long-side "${ROOM_FEATURE_SIDE:-240}" \
    nerfstudio-data || return 1
  local run="$WORK/outputs/$name/cinesplat/gpu_check"
  mkdir -p "$OUT/room"
  cp "$d/geometry.json" "$d/labels.json" "$d/transforms.json" "$run/dataparser_transforms.json" "$run/config.yml" "$OUT/room/"
  $PY - "$run/config.yml" "$OUT/room/$name.pt" <<'EOF' || return 1
import sys, time
from cinenerf_ns.method.checkpoint import export_compact, load_splat
from pathlib import Path
from cinenerf_ns.method.training_cameras import camera_info, training_camera_poses
st = load_splat(sys.argv[1])
p = training_camera_poses(Path(sys.argv[1]))  # where the training cameras were: free space for random starts,
if p is not None:  # what no camera saw fills an object's volume centre, and cinesplat-viewer opens at one of them
    st.info.update(camera_info(p[:, :, 3], p))
t = time.perf_counter(); p = export_compact(st, sys.argv[2], half=True)
print("gaussians", len(st), "step", st.step, "labels", st.info.get("label_names"))
print(f"compact export {p} {p.stat().st_size/2**20:.2f} MiB in {time.perf_counter()-t:.2f}s")
EOF
  # per-object selection vs ground truth (quick look; the full evaluation runs from the compact scene)
  $PY benchmarks/eval_room.py --scene "$OUT/room/$name.pt" --dataset "$OUT/room" --selection-only \
      --out "$OUT/room/eval_gpu" --device cuda || true
}

stage_planner() {
  # planner, candidates and viewer latency on CUDA at ${PLAN_N:-1000000} Gaussians (each capped in time)
  timeout "${PLAN_CAP:-110}" $PY benchmarks/bench_planner.py --device cuda --n-gaussians "${PLAN_N:-1000000}" --pairs "${PLAN_PAIRS:-100}"
  timeout "${CAND_CAP:-80}" $PY benchmarks/bench_candidates.py --device cuda --n-gaussians "${PLAN_N:-1000000}" --k 32 --repeats 3
  timeout "${VIEW_CAP:-50}" $PY benchmarks/bench_viewer.py --device cuda --n-gaussians "${PLAN_N:-1000000}" --repeats 5
  cp benchmarks/RESULTS.md "$OUT/RESULTS.md"; cp benchmarks/bench_planner_cuda_*.json "$OUT/" 2>/dev/null
  return 0
}

stage_demo_render() {
  # the planner's own camera path (cinesplat-plan from text on the room run) rendered by stock ns-render
  local cfg="${RUN_CFG:-$WORK/outputs/room${ROOM_SEED:-0}/cinesplat/gpu_check/config.yml}"
  [ -f "$cfg" ] || { echo "no trained room at $cfg (run the room stage first)"; return 1; }
  $PY -c "from cinenerf_ns.cli.plan import entrypoint; entrypoint()" --scene "$cfg" --go-to "the red armchair" \
      --look-at "the floor lamp" --candidates 4 --output-dir "$OUT/demo_render" --name demo --device cuda || return 1
  if ! command -v ffmpeg > /dev/null; then
    mkdir -p "$WORK/bin"
    printf '#!/bin/sh\necho "ffmpeg stub (gpu_check.sh): real ffmpeg is not installed on this machine" >&2\nexit 1\n' > "$WORK/bin/ffmpeg"
    chmod +x "$WORK/bin/ffmpeg"; export PATH="$WORK/bin:$PATH"
  fi
  ns-render camera-path --load-config "$cfg" --camera-path-filename "$OUT/demo_render/demo_0.json" \
    --output-path "$OUT/demo_render/frames" --output-format images --rendered-output-names rgb || return 1
  echo "rendered frames: $(ls "$OUT/demo_render/frames" | wc -l)"
}

stage_shots() {
  # issue 24 on a GPU: the bundled room's demo shot previewed at 1280x720 / 15 fps through gsplat (mp4 through the
  # imageio-ffmpeg wheel's ffmpeg), the preview-vs-gsplat tests and the stock ns-render mp4 test (no system ffmpeg)
  $PY -c "import imageio_ffmpeg; print('imageio-ffmpeg', imageio_ffmpeg.get_ffmpeg_exe())" || { echo "imageio-ffmpeg missing"; return 1; }
  gsplat_compile || return 1
  $PY -m cinenerf_ns.cli.plan --scene cinenerf_ns/assets/room0.npz --go-to "the red armchair" --look-at "the floor lamp" \
      --output-dir "$OUT/shots" --name demo --workers 0 || return 1
  for k in 1 2 3; do  # the first call warms gsplat's kernels up
    $PY -m cinenerf_ns.preview.cli --scene cinenerf_ns/assets/room0.npz --camera-path "$OUT/shots/demo_0.json" \
        --output-dir "$OUT/shots" --name "demo_720p_$k" --width 1280 --height 720 --fps 15 --device cuda || return 1
  done
  $PY -m pytest -q -ra -p no:cacheprovider tests/preview/test_gpu.py tests/preview/test_ns_render_gpu.py ${PYTEST_ARGS:-}
}

stage_gputests() {
  # only the GPU tests (the CPU suite is CI's): gsplat compiled first, slow ones (training runs) left to their stages
  gsplat_compile || return 1
  $PY -m pytest -q -ra -p no:cacheprovider -m "gpu and not slow" tests
}

stage_latency() {
  # issue 23 on a GPU: request totals (median / p95 / max) per scene family and start mode at $PLAN_N Gaussians, then
  # 32 ranked candidates; runs as FAMILY@MODE (a family: procedural, blobs, fox, npz:PATH, ply:PATH)
  local n=${PLAN_N:-1000000} spec
  for spec in ${LAT_RUNS:-procedural@random procedural@given blobs@given blobs@random}; do
    timeout "${LAT_CAP:-120}" $PY benchmarks/bench_planner.py --device cuda --n-gaussians "$n" --family "${spec%@*}" \
        --start-mode "${spec##*@}" --pairs "${PLAN_PAIRS:-60}" || echo "latency run $spec: rc=$?"
  done
  [ -n "${CAND_FAMILIES:-procedural}" ] && for fam in ${CAND_FAMILIES:-procedural}; do
    timeout "${CAND_CAP:-150}" $PY benchmarks/bench_candidates.py --device cuda --n-gaussians "$n" --family "$fam" \
        --k 32 --repeats 4 || echo "candidates $fam: rc=$?"
  done
  cp benchmarks/RESULTS.md "$OUT/RESULTS.md"
  return 0
}

STAGES=("$@")
[ ${#STAGES[@]} -eq 0 ] && STAGES=(install tests train render viewer labels)
# a fresh machine (or a new call after the machine was recycled): install first
if [ ! -f "$SITE/.cinenerf_installed" ] && [[ " ${STAGES[*]} " != *" install "* ]]; then STAGES=(install "${STAGES[@]}"); fi
log "repo $REPO  out $OUT  fox ${FOX:-<missing>}  stages ${STAGES[*]}"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null | tee -a "$OUT/gpu_check.log"
status=0
for s in "${STAGES[@]}"; do
  run_stage "$s" "stage_$s" || { status=1; log "stage $s FAILED"; [ "$s" = install ] && break; }
done
log "done, status $status; timings:"; cat "$OUT/timings.txt"
exit $status
