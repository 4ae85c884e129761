"""Compiled CPU rasteriser of the preview (raster.c), loaded with ctypes like the planner's kernels.

raster.c is compiled with the system C compiler on first use, twice: ``float`` (previews) and ``double`` (tests
against the float64 torch path), into the same per-user cache as planner/native (keyed by a hash of the source,
the compiler, the flags and the platform; written to a temporary name, then renamed). No compiler, a failed
compile or ``CINENERF_NATIVE=0`` (or ``CINENERF_NATIVE_OFF=preview``): the loaders return None and the preview
uses the pure-torch tiled renderer (preview/raster_torch.py, same images, much slower); ``native_status()`` says why.
"""
from __future__ import annotations

import ctypes
import os
import threading
from pathlib import Path
from typing import Optional

import numpy as np

from cinenerf_ns.planner.native import compile_library, turned_off

_HERE = Path(__file__).resolve().parent
_LOCK = threading.Lock()
_FUNCS: dict[str, object] = {}
_STATUS: dict[str, str] = {}
_VARIANTS = {"float32": ["-DREAL=float"], "float64": ["-DREAL=double", "-DREAL_IS_DOUBLE"]}


def _compile(variant: str) -> Optional[Path]:
    lib, why = compile_library(_HERE / "raster.c", f"preview_raster_{variant}",
                               ["-O3", "-pthread", *_VARIANTS[variant]])
    if lib is None:
        _STATUS[variant] = why
    return lib


def render_fn(dtype: str = "float32"):
    """The compiled ``cn_render`` for ``dtype`` ("float32" | "float64") as a ctypes function, or None."""
    with _LOCK:
        if dtype in _FUNCS:
            return _FUNCS[dtype]
        f = None
        off = turned_off("preview")
        if off is not None:
            _STATUS[dtype] = off
        else:
            path = _compile(dtype)
            if path is not None:
                try:
                    f = ctypes.CDLL(str(path)).cn_render
                    real = ctypes.c_float if dtype == "float32" else ctypes.c_double
                    P, I64 = ctypes.c_void_p, ctypes.c_int64
                    f.argtypes = [P, P, P, P, I64, P, P, I64, I64, real, real, I64, P, P, P]
                    f.restype = I64
                    _STATUS[dtype] = f"compiled: {path}"
                except OSError as e:
                    _STATUS[dtype] = f"loading {path} failed: {e}"
        _FUNCS[dtype] = f
        return f


def native_status() -> dict:
    """dtype -> what happened when the rasteriser was loaded (library path, or why the torch path is used)."""
    return dict(_STATUS)


def default_threads() -> int:
    """CPUs this process may run on (its affinity mask, else os.cpu_count())."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def render_native(
    means: np.ndarray,  # [N, 3] world
    cov3d: np.ndarray,  # [N, 6] xx xy xz yy yz zz
    opacities: np.ndarray,  # [N] activated
    colors: np.ndarray,  # [N, 3]
    viewmat: np.ndarray,  # [4, 4] world -> camera (OpenCV)
    intrinsics: tuple,  # (fx, fy, cx, cy)
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
    threads: int = 0,
    fn=None,
):
    """(premultiplied rgb [H, W, 3], alpha [H, W, 1], stats dict) from the compiled kernel, in the arrays' dtype."""
    dt = np.dtype(means.dtype)
    fn = fn or render_fn(dt.name)
    if fn is None:
        raise RuntimeError("the compiled preview rasteriser did not load: "
                           f"{native_status().get(dt.name, 'not loaded')}")
    arrs = [np.ascontiguousarray(a, dtype=dt) for a in (means, cov3d, opacities, colors, viewmat)]
    n = arrs[0].shape[0]
    assert arrs[1].shape == (n, 6) and arrs[2].shape == (n,) and arrs[3].shape == (n, 3) and arrs[4].shape == (4, 4)
    intr = np.asarray(intrinsics, dtype=dt)
    rgb = np.empty((height, width, 3), dtype=dt)  # [H, W, 3]
    alpha = np.empty((height, width, 1), dtype=dt)  # [H, W, 1]
    stats = np.zeros(2, dtype=np.int64)
    threads = threads or default_threads()
    ptr = lambda a: a.ctypes.data  # noqa: E731
    rc = fn(*(ptr(a) for a in arrs[:4]), n, ptr(arrs[4]), ptr(intr), int(width), int(height), float(near_plane),
            float(eps2d), int(threads), ptr(rgb), ptr(alpha), ptr(stats))
    if rc < 0:
        raise MemoryError("the preview rasteriser ran out of memory")
    return rgb, alpha, {"visible": int(stats[0]), "intersections": int(stats[1])}
