"""Optional compiled kernels of the planner (plain C, loaded with ctypes; no Python C API, no build step).

The C source ships with the package and is compiled with the system C compiler (``$CC``, else ``cc``) on first
use into a per-user cache (``$CINENERF_CACHE`` or ``$XDG_CACHE_HOME/cinenerf_ns`` or ``~/.cache/cinenerf_ns``),
keyed by a hash of the source, the compiler and the platform, so a changed source is rebuilt and concurrent
processes never load a half-written library (it is written to a temporary name, then renamed). Everything here
is an accelerator: when no compiler is found, compiling fails, or ``CINENERF_NATIVE=0`` is set, the loaders return
None and the callers use their pure-Python code (same results, slower; ``native_status()`` says why).
``CINENERF_NATIVE_OFF=polytope,astar26`` turns off only the libraries named (for A/B benchmarks).

Why C and not a Python extension: nerfstudio users already have a C compiler (gsplat compiles its CUDA code with
it), the kernels need no Python objects, and a ctypes library needs no headers or build isolation.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Optional, Sequence, Tuple

from ..errors import InvalidInputError

_HERE = Path(__file__).resolve().parent
_LOCK = threading.Lock()
_LIBS: dict[str, Optional[ctypes.CDLL]] = {}
_STATUS: dict[str, str] = {}


def cache_dir() -> Path:
    """Where compiled libraries are kept (see the module docstring)."""
    if os.environ.get("CINENERF_CACHE"):
        return Path(os.environ["CINENERF_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "cinenerf_ns"


def enabled() -> bool:
    """False when the user turned compiled kernels off (CINENERF_NATIVE=0)."""
    return os.environ.get("CINENERF_NATIVE", "1").strip().lower() not in ("0", "false", "no", "off")


def turned_off(name: str) -> Optional[str]:
    """Why the compiled library ``name`` is not to be used (CINENERF_NATIVE=0, or listed in CINENERF_NATIVE_OFF), or
    None."""
    if not enabled():
        return "turned off (CINENERF_NATIVE=0)"
    if name in {x.strip() for x in os.environ.get("CINENERF_NATIVE_OFF", "").split(",") if x.strip()}:
        return "turned off (CINENERF_NATIVE_OFF)"
    return None


def compile_library(src: Path, stem: str, flags: Sequence[str]) -> Tuple[Optional[Path], str]:
    """(path of the shared library compiled from ``src`` with ``flags``, "") from the cache (keyed by the source, the
    compiler, the flags and the platform), compiled on first use; (None, why) when there is no compiler or it fails."""
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        return None, "no C compiler found (set CC)"
    key = hashlib.sha256(src.read_bytes() + " ".join([cc, *flags]).encode() + platform.machine().encode()
                         + sys.platform.encode()).hexdigest()[:16]
    lib = cache_dir() / f"{stem}-{key}.so"
    if lib.exists():
        return lib, ""
    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{stem}-", suffix=".so", dir=lib.parent)
        os.close(fd)
        r = subprocess.run([cc, *flags, "-shared", "-fPIC", "-o", tmp, str(src), "-lm"], capture_output=True,
                           text=True, timeout=120)
        if r.returncode != 0:
            os.unlink(tmp)
            return None, f"compiling {src.name} failed: {r.stderr.strip()[:300]}"
        os.replace(tmp, lib)  # atomic: another process sees the old state or the whole library
    except (OSError, subprocess.SubprocessError) as e:
        return None, f"compiling {src.name} failed: {e}"
    return lib, ""


_FLAGS = {"visibility": ["-O2", "-pthread"], "voxelrays": ["-O2", "-pthread"],
          "occupancy": ["-O3", "-ffp-contract=off", "-fno-math-errno"]}
"""Compiler flags of the libraries that need more than -O2 (visibility.c and voxelrays.c split their work over threads;
occupancy.c's column loop is vectorised at -O3, its sqrtf needs no errno, and it must round as torch does: no
contraction into fused multiply-adds, never -ffast-math)."""
_THREADS: Optional[int] = None
MAX_KERNEL_THREADS = 64
"""Most threads a compiled kernel starts (visibility.c's MAX_THREADS)."""


def set_kernel_threads(n: Optional[int]) -> None:
    """Threads a multi-threaded kernel may use in this process (None: the default, kernel_threads). A forked candidate
    worker sets 1: its siblings use the other CPUs."""
    global _THREADS
    if n is not None and not 1 <= int(n) <= MAX_KERNEL_THREADS:
        raise InvalidInputError(f"kernel threads must be in [1, {MAX_KERNEL_THREADS}], got {n}")
    _THREADS = None if n is None else int(n)


def kernel_threads() -> int:
    """Threads a multi-threaded kernel may use: set_kernel_threads, else $CINENERF_THREADS, else the CPUs this
    process may run on, at most 8 (the kernels' work per call is small: more threads cost more than they save)."""
    if _THREADS is not None:
        return _THREADS
    env = os.environ.get("CINENERF_THREADS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            n = 0
        if not 1 <= n <= MAX_KERNEL_THREADS:  # never clamped silently
            raise InvalidInputError(f"CINENERF_THREADS must be a whole number in [1, {MAX_KERNEL_THREADS}], got "
                                    f"{env[:20]!r}")
        return n
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    return max(1, min(8, cpus))


def _compile(name: str) -> Optional[Path]:
    lib, why = compile_library(_HERE / f"{name}.c", name, _FLAGS.get(name, ["-O2"]))
    if lib is None:
        _STATUS[name] = why
    return lib


def load(name: str) -> Optional[ctypes.CDLL]:
    """The compiled library ``name`` (from ``native/<name>.c``), or None (see native_status)."""
    with _LOCK:
        if name in _LIBS:
            return _LIBS[name]
        lib = None
        off = turned_off(name)
        if off is not None:
            _STATUS[name] = off
        else:
            path = _compile(name)
            if path is not None:
                try:
                    lib = ctypes.CDLL(str(path))
                    _STATUS[name] = f"compiled: {path}"
                except OSError as e:
                    _STATUS[name] = f"loading {path} failed: {e}"
        _LIBS[name] = lib
        return lib


def choose(backend: str, loader, lib: str, what: str, applies: bool = True, needs: str = ""):
    """The compiled function a caller with a ``backend`` argument ("auto" | "native" | "python") should use:
    ``loader()`` when it applies and loads, else None (the Python path). Raises InvalidInputError for an unknown
    backend and RuntimeError when "native" was asked for and cannot be had (``needs``: what the compiled path needs)."""
    if backend not in ("auto", "native", "python"):
        raise InvalidInputError(f"{what} backend must be 'auto', 'native' or 'python', got {backend!r}")
    fn = loader() if backend != "python" and applies else None
    if fn is None and backend == "native":
        if not applies:
            raise RuntimeError(f"the compiled {what} does not apply here (it needs {needs})")
        raise RuntimeError(f"the compiled {what} did not load: {native_status().get(lib, 'not loaded')}")
    return fn


def native_status() -> dict:
    """name -> what happened when it was loaded (compiled path, or why the Python fallback is used)."""
    return dict(_STATUS)


_FUNCS: dict[str, object] = {}


def _function(lib_name: str, name: str, argtypes: list, restype):
    """ctypes function ``name`` of library ``lib_name`` with its signature set (cached), or None."""
    if name not in _FUNCS:
        lib = load(lib_name)
        f = None
        if lib is not None:
            f = getattr(lib, name)
            f.argtypes = argtypes
            f.restype = restype
        _FUNCS[name] = f
    return _FUNCS[name]


_I64, _P, _F64 = ctypes.c_int64, ctypes.c_void_p, ctypes.c_double


def astar26():
    """The compiled A* (astar26.c) as a ctypes function, or None."""
    return _function("astar26", "astar26", [_P, _I64, _I64, _I64, _I64, _I64, _F64, _I64, _P, _I64], _I64)


def search26():
    """The compiled search26 (astar26.c: A* to a goal, or Dijkstra to the nearest marked voxel), or None."""
    return _function("astar26", "search26", [_P, _I64, _I64, _I64, _I64, _I64, _P, _F64, _I64, _P, _I64], _I64)


def search26_ws():
    """search26 with the caller's workspace (astar26.c: search26_ws; astar.AStarGrid keeps it), or None."""
    return _function("astar26", "search26_ws",
                     [_P, _I64, _I64, _I64, _I64, _I64, _P, _F64, _I64, _P, _I64, _P, _I64, _P, _P], _I64)


def search26_ws_lm():
    """search26_ws with landmark tables (astar26.c: search26_ws_lm; search/landmarks.py), or None."""
    return _function("astar26", "search26_ws_lm",
                     [_P, _I64, _I64, _I64, _I64, _I64, _P, _F64, _I64, _P, _I64, _P, _I64, _P, _P, _P, _I64], _I64)


def search26_wsr():
    """search26_ws_lm that a budget may interrupt and a later call resume (astar26.c: search26_wsr), or None."""
    return _function("astar26", "search26_wsr",
                     [_P, _I64, _I64, _I64, _I64, _I64, _P, _F64, _I64, _P, _I64, _P, _I64, _P, _P, _P, _I64, _P, _I64,
                      _P], _I64)


def dist26():
    """The compiled shortest-path distances from one voxel to all (astar26.c: dist26), or None."""
    return _function("astar26", "dist26", [_P, _I64, _I64, _I64, _I64, _P], _I64)


_I32 = ctypes.c_int32
# the scene and index arguments every polytope.c entry point starts with (geometry/native_scene.py: native_arrays)
_SCENE_INDEX = [_P, _P, _P, _P, _I32,  # scene: means, rotations, radii, packed rows [N, 12] float32, float32 flag
                _P, _I32, _P, _P, _P, _P, _P, _F64]  # index: origin, levels, cells, dims, offsets*, ids*, homes*, pad


def safe_polytope_c():
    """The compiled safe polytope of a point or segment seed (polytope.c: cn_safe_polytope), or None."""
    return _function(
        "polytope", "cn_safe_polytope",
        [*_SCENE_INDEX,
         _P, _I32, _P, _P, _P,  # seeds, count, box lo, hi, rotation (or NULL)
         _F64, _F64, _I32, _I32, _F64, _F64,  # camera radius, margin, normal rule, seed inside, near fraction, shrink
         _I64, _P, _P, _P, _P, _P, _P],  # cap, planes n, b, ids, bad ids, bad slacks, info
        _I64)


def safe_polytopes_aabb_c():
    """The compiled safe polytopes of K segment seeds in their axis-aligned boxes, one call (polytope.c:
    cn_safe_polytopes_aabb), or None."""
    return _function(
        "polytope", "cn_safe_polytopes_aabb",
        [*_SCENE_INDEX,
         _P, _I64, _P, _P,  # seeds [K, 2, 3], K, box lo [K, 3], hi [K, 3]
         _F64, _F64, _I32, _I32, _F64, _F64,  # camera radius, margin, normal rule, seed inside, near fraction, shrink
         _I64, _P, _P, _P, _P, _P, _P, _P],  # cap, planes n, b, ids, bad ids, bad slacks (scratch), seg [K, 3], info
        _I64)


def planes_empty_c():
    """The compiled emptiness proof of a polytope's planes (polytope.c: cn_planes_empty), or None."""
    return _function("polytope", "cn_planes_empty", [_P, _P, _I64, _F64, _P, _F64], _I64)


def points_collide_c():
    """The compiled Corollary-1 point test (polytope.c: cn_points_collide), or None."""
    return _function(
        "polytope", "cn_points_collide",
        [*_SCENE_INDEX,
         _P, _P, _I64, _F64, _P],  # points [P, 3], radii [P], P, margin, hit [P] uint8 (out)
        _I64)


def points_distance_c():
    """The compiled capped exact point distance (polytope.c: cn_points_distance), or None."""
    return _function(
        "polytope", "cn_points_distance",
        [*_SCENE_INDEX,
         _P, _I64, _F64, _P],  # points [P, 3], P, max distance, out [P]
        _I64)


def segments_blocked_c():
    """The compiled sight-line test (polytope.c: cn_segments_blocked), or None."""
    return _function(
        "polytope", "cn_segments_blocked",
        [*_SCENE_INDEX,
         _P, _P, _I64, _F64, _P, _P,  # p0 [L, 3], p1 [L, 3], L, piece length, skip [N] uint8 or NULL, out [L]
         _P, _P, _F64, _P],  # free-voxel proof or NULLs: occ uint8 [X, Y, Z], grid lo [3], voxel size, dims [3]
        _I64)


def box_distance_c():
    """The compiled distance to the nearest occupied voxel box (polytope.c: cn_box_distance), or None."""
    return _function(
        "polytope", "cn_box_distance",
        [_P, _P, _F64, _P, _P, _I64, _I64, _F64, _P],  # occ, grid lo, voxel size, dims, points, P, window, cap, out
        _I64)


def segments_free_c():
    """The compiled voxel walk (gridpoly.c: cn_segments_free), or None."""
    return _function("gridpoly", "cn_segments_free", [_P, _P, _P, _F64, _P, _P, _I64, _F64, _P], _I64)


def shortcut_rounds_c():
    """The compiled shortcut rounds up to the Corollary-1 pieces (gridpoly.c: cn_shortcut_rounds), or None."""
    return _function("gridpoly", "cn_shortcut_rounds",
                     [_P, _P, _P, _F64, _F64,  # walk grid: occ uint8 [X, Y, Z], dims [3], lo [3], voxel size; eps
                      _P, _P, _P, _F64, _I64,  # free-voxel grid: occ, dims, lo, voxel size; grid rule flag
                      _P, _P, _I64,  # points [N, 3], offsets [W + 1], W
                      _P, _P, _P, _P, _P],  # keep [N], nkeep [W], best [W], cand [N], ncand [W] (int64, in/out)
                     _I64)


def sort_cubes_c():
    """The grid polytope's cube sort on its own (gridpoly.c: cn_sort_cubes; for its test), or None."""
    return _function("gridpoly", "cn_sort_cubes", [_P, _I64, _I64, _P], _I64)


def grid_polytope_c():
    """The compiled grid polytope planes (gridpoly.c: cn_grid_polytope), or None."""
    return _function("gridpoly", "cn_grid_polytope", [_P, _P, _P, _P, _P, _P, _F64, _I64, _P, _P], _I64)


def grid_polytope_world_c():
    """The compiled grid polytope of a world segment, voxel walk and box included (gridpoly.c:
    cn_grid_polytope_world), or None."""
    return _function("gridpoly", "cn_grid_polytope_world",
                     [_P, _P, _P, _P, _F64, _P, _P, _F64, _F64, _F64, _I64, _P, _P],  # occ, surface, dims, lo, vs,
                     _I64)  # a, c, box margin, margin, eps, cap, out normals [cap, 3], out offsets [cap]


def grid_polytopes_world_c():
    """The compiled grid polytopes of a polyline's segments in one call (gridpoly.c: cn_grid_polytopes_world), or
    None."""
    return _function("gridpoly", "cn_grid_polytopes_world",
                     [_P, _P, _P, _P, _F64,  # occ, surface, dims, lo, voxel size
                      _P, _I64, _P, _F64, _F64, _F64,  # points [n + 1, 3], n, skip [n], box margin, margin, eps
                      _I64, _P, _P, _P],  # cap, out normals [cap, 3], out offsets [cap], counts [n]
                     _I64)


def hidden_voxels_c():
    """The compiled sampled sight lines (voxelrays.c: cn_hidden_voxels; method/object_centre.hidden_voxels), or None."""
    return _function("voxelrays", "cn_hidden_voxels", [_P, _I64, _I64, _I64, _P, _I64, _P, _I64, _F64, _P, _I64],
                     _I64)


def occupancy_c():
    """The compiled occupancy rasterisation (occupancy.c; scene/occupancy.build_occupancy): its entry points
    (cn_occupancy_footprints, cn_occupancy_discs, cn_occupancy_mark, cn_occupancy_sum) as ctypes functions, or None."""
    fns = (_function("occupancy", "cn_occupancy_footprints",
                     [_P, _P, _I32, _I64, _P, _F64, _I64, _I64, _I64, _F64,  # means, half-extents, float32 flag, N,
                      _P, _P], _I64),  # grid lo [3], voxel size, X, Y, Z, rho; out: first index [N, 3], span [N, 2]
           _function("occupancy", "cn_occupancy_discs",
                     [_P, _P, _P, _I32, _I64, _I64, _P, _P,  # means, rotations, radii, float32 flag, e0, e1, ilo, span
                      _P, _F64, _F64, _P, _I64, _P, _F64,  # grid lo, voxel, rho, t [S], S, powers or NULL, 1 + margin
                      _P, _P, _P, _P, _I64], _I64),  # out: mc [E, S, 6], m6 [E, S, 6] or NULL, mu [E, 3], disc [cap]
           _function("occupancy", "cn_occupancy_mark",
                     [_I64, _I64, _P, _P, _P, _P, _I64,  # e0, e1, ilo, span, mc, mu, S
                      _P, _I64, _I64, _I64, _P,  # square roots [n], n, Y, Z, diff [X Y (Z + 1)] int32
                      _P, _P, _P], _I64),  # or (tests) out z0, z1 [columns] float32, ok [columns] uint8; else NULLs
           _function("occupancy", "cn_occupancy_sum", [_P, _I64, _I64, _I64, _P], None))  # diff, X, Y, Z, out occ
    return None if any(f is None for f in fns) else fns


def project_primal_c():
    """The compiled primal active-set projection onto a polytope (project.c: cn_project_primal; goal.py), or None."""
    return _function("project", "cn_project_primal", [_P, _P, _I64, _P, _P, _I64, _P], _I64)


def project_dual_c():
    """The compiled dual active-set projection onto a polytope (project.c: cn_project_dual; goal.py), or None."""
    return _function("project", "cn_project_dual", [_P, _P, _I64, _P, _I64, _P], _I64)


# the curve arguments both timing.c entry points start with (timing._native_curve)
_CURVE = [_P, _I64, _I64,  # power coefficients of p' [M, n+1, 3], M, n+1
          _P, _P, _F64]  # segment starts [M], durations [M], total duration


def arc_length_table_c():
    """The compiled arc-length table (timing.c: cn_arc_length_table; trajectory/timing.arc_length_table), or None."""
    return _function("timing", "cn_arc_length_table",
                     [*_CURVE, _I64, _P, _P,  # samples per segment, Gauss-Legendre nodes [5], weights [5]
                      _P, _P, _P],  # out: tau [K], s [K], speed at tau [K] or NULL
                     _I64)


def invert_arc_length_c():
    """The compiled arc-length inversion (timing.c: cn_invert_arc_length; trajectory/timing.invert_arc_length with
    the table's speeds), or None."""
    return _function("timing", "cn_invert_arc_length",
                     [*_CURVE, _P, _P,  # Gauss-Legendre nodes [5], weights [5]
                      _P, _P, _P, _I64,  # table: tau [K], s [K], speed [K], K
                      _P, _I64, _F64, _P],  # arc lengths s [T], T, Newton tolerance, out: tau [T]
                     _I64)


# the curve arguments the dense-sampling and position entry points start with (timing.native_bezier)
_BEZIER = [_P, _I64, _I64,  # control points [M, D+1, 3], M, D+1
           _P, _P, _F64]  # segment starts [M], durations [M], total duration


def dense_counts_c():
    """The compiled piece counts of the verification's dense samples (timing.c: cn_dense_counts;
    shots/safety.dense_samples), or None."""
    return _function("timing", "cn_dense_counts",
                     [*_BEZIER, _P, _P, _I64, _F64,  # frame positions [T, 3], curve times [T], T, max spacing
                      _P, _P],  # out: speed bound per segment [M], pieces per frame interval [T-1] (int64)
                     _I64)


def dense_fill_c():
    """The compiled dense samples from their counts (timing.c: cn_dense_fill; shots/safety.dense_samples), or None."""
    return _function("timing", "cn_dense_fill",
                     [*_BEZIER, _P, _P, _P, _I64, _P,  # speed bounds [M], frame times [T], curve times [T], T, sub
                      _P, _P, _P],  # out: times [S+1], positions [S+1, 3], piece lengths [S]
                     _I64)


def bezier_positions_c():
    """The compiled curve positions at curve times (timing.c: cn_bezier_positions; BezierTrajectory.evaluate for
    timing.time_parametrize's frames), or None."""
    return _function("timing", "cn_bezier_positions",
                     [*_BEZIER, _P, _I64, _P],  # curve times [T], T, out: positions [T, 3]
                     _I64)


def look_at_c():
    """The compiled look-at rotations (orientation.c: cn_look_at; trajectory/orientation.look_at_rotations for frames
    away from the target and the singular cone), or None."""
    return _function("orientation", "cn_look_at",
                     [_P, _P, _I64, _I64, _P, _F64, _P],  # positions [T, 3], target, target per frame, T, up [3],
                     _I64)  # singular_sin, out: rotations [T, 3, 3]


def corridor_dual_c():
    """The compiled corridor QP by its equality-free form and the dual active-set method (dual_qp.c:
    cn_corridor_dual; trajectory/dual_qp.py), or None."""
    return _function("dual_qp", "cn_corridor_dual",
                     [_I64, _I64, _I64, _I64, _P, _P, _P, _P,  # M, degree, continuity, factor rows, durations,
                      # factors [M, rows, D+1], diffs, kinds
                      _P, _P, _P, _P, _F64, _I64,  # start/goal [2, 3], faces A [F, 3], b' [F], face starts [M+1], tol,
                      # max_iter
                      _P, _P],  # out: control points [N, 3], info [2]
                     _I64)


def goal_window_c():
    """The compiled window of the goal's voxel fallback (goalwindow.c: cn_goal_window; search/goal.py), or None."""
    return _function("goalwindow", "cn_goal_window",
                     [_P, _P, _I64, _P, _P, _P, _P, _P,  # occ, labels or NULL, comp, reach or NULL, mean, dims, a, e
                      _P, _F64, _P, _I64,  # grid lo [3], voxel size, target [3], limit
                      _P, _P],  # out: centres [limit, 3], smallest distance
                     _I64)


def optical_depth_c():
    """The compiled optical depth of segments through semi-transparent Gaussians (visibility.c: cn_optical_depth;
    geometry/visibility.py), or None."""
    return _function("visibility", "cn_optical_depth",
                     [_P, _P, _P, _I64,  # packed [N, 13] (mean, whitening rows, opacity), sph [N, 4] (mean, bound)
                      # or NULL, class [N] uint8, N
                      _P, _F64, _P, _P, _P,  # grid lo [3], cell, dims [3], cell starts [C + 1], cell ids [E] int32
                      _F64, _P, _P, _P,  # coarse grid (same lo): cell (<= 0: none), dims, cell starts, cell ids
                      _P, _I64, _F64,  # big ids int32, their count, cut-off m^2
                      _P, _P, _P, _I64, _F64,  # p0 [L, 3], p1 [L, 3], skip [L] int64, L, stop1,
                      _F64, _P, _P, _I64],  # stop0, after1 [L] or NULL, out tau [L, 2], threads
                     _I64)


def member_box_c():
    """The compiled box of an object's Gaussians' cut-off boxes and running sum of their cover (targets.c:
    cn_member_box; geometry/visibility.py subject_box, SubjectSamples.of_members), or None."""
    return _function("targets", "cn_member_box",
                     [_P, _I64, _P, _P, _P,  # members [K] int64, K, means [N, 3], half [N, 3], cover [N] or NULL
                      _P, _P, _P],  # out: lo [3], hi [3], cum [K] (or NULL without cover)
                     _I64)


def subject_size_c():
    """The compiled size and wholeness of a subject in cameras' frames (targets.c: cn_subject_size;
    shots/framing.py subject_size), or None."""
    return _function("targets", "cn_subject_size",
                     [_P, _I64, _P, _P, _P, _I64,  # cameras [M, 3], M, look-at [3], up [3], points [P, 3], P
                      _F64, _F64, _F64, _F64,  # pad, tan half fov across, down, in-frame limit
                      _P, _P],  # out: size [M], whole [M] uint8
                     _I64)


def nearest_gaps_c():
    """The compiled distance of each point to its nearest other point (targets.c: cn_nearest_gaps;
    shots/target_object.py's spacing), or None."""
    return _function("targets", "cn_nearest_gaps", [_P, _I64, _P, _P],  # points [P, 3], P, order by x [P], out [P]
                     _I64)


def coverage_c():
    """The compiled raster of a go-to object's frame coverage (targets.c: cn_coverage; shots/end_pose.py
    frame_coverage), or None."""
    return _function("targets", "cn_coverage",
                     [_P, _P, _P, _P, _P, _I64, _I64,  # x, y, rx, ry [M, P], front [M, P] uint8, M, P
                      _P, _I64, _P, _I64, _P, _P],  # cx [nx], nx, cy [ny], ny, scratch [nx ny] uint8, out [M]
                     _I64)


def bracket_c():
    """The compiled pass of target_object.exact_median (targets.c: cn_bracket), or None."""
    return _function("targets", "cn_bracket", [_P, _I64, _F64, _F64, _P, _P],  # v [n], n, lo, hi, out mid [n],
                     _I64)  # out counts [2] (below lo, above hi)
