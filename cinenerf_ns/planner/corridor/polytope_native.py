"""Host side of the compiled safe polytope (native/polytope.c): the safe-polytope call and the emptiness proof.

Every polytope.c entry point (the safe polytope, the point test, the capped distance, the sight-line test) starts
with the same scene and index arguments, built once per scene / index pair by geometry/native_scene.py's
``native_arrays``. Their Python references are polytope.safe_polytope, collision.points_collide, distance.clearance
and occlusion.segments_blocked (``backend="python"``); the tests compare each pair.
"""
from __future__ import annotations

import numpy as np

from ..geometry.native_scene import native_arrays

NORMAL_CODE = {"auto": 0, "prop2": 1, "mahalanobis": 2, "closest": 3}  # polytope.c's normal rule numbers
FIRST_CAP = 512  # planes the first output buffer holds; a polytope with more is built again with room for all


def native_safe_polytope(fn, scene, index, seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray, rot, r: float,
                         margin: float, normal: str, require_seed_inside: bool, near_fraction: float,
                         empty_shrink: float = -1.0):
    """One cn_safe_polytope call (float64 seeds [S, 3], box lo / hi [3], rot [3, 3] or None; near_fraction 0: one
    pass; empty_shrink >= 0: stop after the first pass when its planes hold no ball of that radius) -> (normals
    [F, 3], offsets [F], scene ids [F] of the planes, scene ids [J] and slacks [J] of the ellipsoids that cut the
    seeds; J > 0 only when ``require_seed_inside``; stopped: True when the second pass was skipped that way)."""
    arr = native_arrays(scene, index)
    # one input block (seeds, box lo, hi, rotation) and one output block, each passed as base pointer + offsets: a
    # numpy array's .ctypes.data costs ~0.8 us, and a call needed ten of them
    S = int(np.shape(seeds)[0])
    inp = np.concatenate([np.asarray(seeds, dtype=np.float64).reshape(-1), np.asarray(lo, dtype=np.float64).reshape(3),
                          np.asarray(hi, dtype=np.float64).reshape(3),
                          np.zeros(0) if rot is None else np.asarray(rot, dtype=np.float64).reshape(9)])
    ip = inp.ctypes.data
    lo_p, hi_p = ip + 8 * 3 * S, ip + 8 * (3 * S + 3)
    rot_p = None if rot is None else ip + 8 * (3 * S + 6)
    cap = FIRST_CAP
    while True:
        out = np.empty(7 * cap + 5)  # planes n [cap, 3], b [cap], ids [cap], bad ids [cap], bad slacks [cap], info [5]
        op = out.ctypes.data
        F = int(fn(
            *arr["args"], ip, S, lo_p, hi_p, rot_p, r, float(margin), NORMAL_CODE[normal],
            int(bool(require_seed_inside)), float(near_fraction), float(empty_shrink), cap, op, op + 8 * 3 * cap,
            op + 8 * 4 * cap, op + 8 * 5 * cap, op + 8 * 6 * cap, op + 8 * 7 * cap))
        info = out[7 * cap:].view(np.int64)
        if F == -2:  # more planes than ``cap``: info[2] says how many
            cap = int(info[2]) + 1
            continue
        if F < 0:
            raise MemoryError(f"the compiled safe polytope failed (code {F})")
        break
    n_planes, b_planes = out[:3 * cap].reshape(cap, 3), out[3 * cap:4 * cap]
    ids_planes, bad_ids = out[4 * cap:5 * cap].view(np.int64), out[5 * cap:6 * cap].view(np.int64)
    bad_slack = out[6 * cap:7 * cap]
    nbad = int(info[0])
    perm = arr["perm"]  # the compiled ids are positions in spatial order
    return n_planes[:F], b_planes[:F], perm[ids_planes[:F]], perm[bad_ids[:nbad]], bad_slack[:nbad], bool(info[4])


def planes_empty_native(fn, A: np.ndarray, b: np.ndarray, shrink: float, centre: np.ndarray, half: float) -> bool:
    """cn_planes_empty: True when {x : A x <= b - shrink |A_f|} (A [F, 3], b [F]) has no point in the cube
    |x - centre|_inf <= half (an exact-arithmetic proof up to rounding that errs towards False)."""
    A_c, b_c = np.ascontiguousarray(A, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64)
    c_c = np.ascontiguousarray(centre, dtype=np.float64)
    res = int(fn(A_c.ctypes.data, b_c.ctypes.data, A_c.shape[0], float(shrink), c_c.ctypes.data, float(half)))
    if res < 0:
        raise MemoryError("the compiled emptiness proof ran out of memory")
    return bool(res)
