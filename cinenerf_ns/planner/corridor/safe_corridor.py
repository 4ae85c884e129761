"""Safe flight corridor: one safe polytope per segment of a (shortcut) polyline.

Polytope m is seeded by the whole segment [w_m, w_{m+1}] (both endpoints, hence the segment, inside),
in a local box = segment bounding box grown by ``box_margin``. Consecutive polytopes share the
waypoint w_{m+1}, so their intersection is never empty; we also measure how much room it has
(Chebyshev radius of P_m ∩ P_{m+1}: a cheap lower bound first, the LP only when that is small),
because C1/C2 Bezier joins want control points on both sides of the junction. The straight polyline
itself is always a feasible trajectory of the corridor, so a thin junction only costs smoothness,
never safety or feasibility; it is reported (``thin_joints``) and warned about.

A segment that no polytope can contain (it grazes an obstacle closer than the camera radius: the
per-ellipsoid planes are tangent to the inflated ellipsoid, so for a segment outside every inflated
ellipsoid this is rare) is split at its midpoint and retried, up to ``max_split_depth`` times.

``backend="batched"`` builds the polytopes of all segments in one batched torch computation
(polytope_batched.py; on a GPU scene + index this is one set of big kernels instead of a host loop per
segment), possibly on another copy of the scene (``batch_scene``/``batch_index``, e.g. the planner's GPU
scene while requests use a CPU mirror). Segments it flags (no polytope found around them) go through the
host path above, splitting included, so both backends cover the same segments with the same guarantee.

``grid`` (a grid_polytope.VoxelObstacles of the planner's occupancy grid): segments that lie in free voxels get a
polytope built from the grid's surface voxels instead (grid_polytope.py: same guarantee, no Gaussian query, a
fraction of the cost, up to about a voxel more conservative); only the other segments (typically the last one,
ending next to the go-to object) need Prop-2 polytopes from either backend.

``split_long`` (with ``grid``): a segment longer than this that neither a known nor a grid polytope covers is bisected
(exact midpoints on the segment, so the polyline keeps its shape) until each piece is in free voxels or no longer
than ``split_long``; consecutive free pieces are merged back into one grid polytope. A Prop-2 polytope's box is the
segment's bounding box plus the margin, so the ellipsoids it must decide grow with the segment's length: a long
shortcut segment that grazes one occupied voxel cost a single long Prop-2 polytope of hundreds of thousands of
candidate ellipsoids; split, it is a few grid polytopes and one or two short Prop-2 ones (docs/PLANNER_DEFAULTS.md,
SPLIT_LONG_MARGINS). Each piece's
polytope holds the piece, so the guarantee is the same; the corridor only has more, smaller polytopes there.
"""
from __future__ import annotations

import inspect
import math
import warnings
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError, PlanningError
from ..host_pool import ordered_map
from ..tensor_pickle import NumpyPickled
from .corridor_trim import MERGE_ROOM, REGION_A, TABLE_MIN_SEGMENTS, merged_runs, region_rows, slack_table
from .polytope import Polytope, SeedNotFreeError, aabb_polytope, chebyshev_center, safe_polytope
from .polytope_batched import safe_polytopes_batched
from .polytope_many import aabb_polytopes
from .polytope_planes import segment_frame_np


def _host_planes(p: Polytope) -> tuple[np.ndarray, np.ndarray]:
    """Polytope.to_numpy: views of CPU float64 planes (Polytope.host_arrays, kept) without its four conversions each
    (the QP's input per request)."""
    got = p.host_arrays()
    if got is not None and got[0].dtype == np.float64 and got[1].dtype == np.float64:
        return got
    return p.to_numpy()


class CorridorError(PlanningError):
    """A path segment stays within the camera radius of the scene even after splitting."""


@dataclass
class Corridor(NumpyPickled):
    """Polytopes P_0..P_{M-1} around the segments of waypoints w_0..w_M (P_m contains [w_m, w_{m+1}]). Pickles its
    CPU tensors as numpy (tensor_pickle.py)."""

    polytopes: list[Polytope]
    waypoints: Tensor  # [M+1, 3] float64
    overlap_radius: Tensor = field(default=None)  # [M-1] lower bound of the Chebyshev radius of P_m ∩ P_{m+1}
    thin_joints: list[int] = field(default_factory=list)  # m with overlap_radius[m] < min_overlap
    n_splits: int = 0  # midpoint splits that were needed
    n_host_segments: int = 0  # backend "batched": segments it flagged, built by the host path instead
    n_grid_segments: int = 0  # segments whose polytope came from the occupancy grid (grid_polytope.py)
    n_known_segments: int = 0  # segments that reused a ``known`` polytope (e.g. the goal's)
    n_long_pieces: int = 0  # extra segments from splitting long off-grid segments (``split_long``)
    n_merged: int = 0  # segments merged into a neighbour's polytope (``merge``: corridor_trim.merged_pieces)
    region: Optional[tuple] = None  # (lo [3], hi [3]) the planning region: every polytope is cut to it

    def __len__(self) -> int:
        return len(self.polytopes)

    def constraints(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """[(A [F,3], b [F])] float64 numpy, one per segment (what the trajectory QP consumes). With a region each
        polytope also gets those of the region's six faces it does not imply already (corridor_trim.region_rows: its
        own box face on the same axis row, at or inside the region's): the curve (in the control points' hull) stays
        inside the region."""
        out = [_host_planes(p) for p in self.polytopes]
        if self.region is None:
            return out
        lo, hi = (np.asarray(v, dtype=np.float64).reshape(3) for v in self.region)
        box_b = np.concatenate([hi, -lo])  # [6]
        if len(out) < TABLE_MIN_SEGMENTS:  # all six faces each: cheaper than finding those implied
            return [(np.concatenate((a, REGION_A)), np.concatenate((b, box_b))) for a, b in out]
        need = region_rows(out, lo, hi)  # [M, 6]
        return [(np.concatenate((a, REGION_A[nd])), np.concatenate((b, box_b[nd]))) if nd.any() else (a, b)
                for (a, b), nd in zip(out, need)]

    @property
    def num_faces(self) -> list[int]:
        return [p.num_faces for p in self.polytopes]


def _segment_polytopes(p0, p1, scene, index, box_margin, depth, max_depth, kw, out, stats, seg_id, box):
    """Append (Polytope, p0, p1) for the segment p0 -> p1 (float64 numpy [3]) to ``out``, split at midpoints while
    its seed is not free (up to max_depth levels)."""
    if box == "oriented":
        rot = segment_frame_np(p0, p1)
        sb = np.stack([p0, p1]) @ rot  # segment in box coordinates
        poly = _try(safe_polytope, np.stack([p0, p1]), scene, index, sb.min(0) - box_margin, sb.max(0) + box_margin,
                    box_rotation=rot, **kw)
    else:
        poly = _try(aabb_polytope, np.stack([p0, p1]), scene, index, np.minimum(p0, p1) - box_margin,
                    np.maximum(p0, p1) + box_margin, **kw)
    if not isinstance(poly, SeedNotFreeError):
        out.append((poly, p0, p1))
        return
    if depth >= max_depth:
        raise CorridorError(
            f"path segment {seg_id} ({p0.tolist()} -> {p1.tolist()}) passes within the camera radius of "
            f"the scene (worst slack {poly.min_slack:.3g}) even after {max_depth} splits; the initial path is "
            f"not collision-free (check the occupancy grid / shortcut segment test)"
        ) from poly
    stats["splits"] += 1
    mid = 0.5 * (p0 + p1)
    _segment_polytopes(p0, mid, scene, index, box_margin, depth + 1, max_depth, kw, out, stats, seg_id, box)
    _segment_polytopes(mid, p1, scene, index, box_margin, depth + 1, max_depth, kw, out, stats, seg_id, box)


def _try(fn, *args, **kw):
    """fn(*args, **kw), or the SeedNotFreeError it raised."""
    try:
        return fn(*args, **kw)
    except SeedNotFreeError as e:
        return e


def build_corridor(
    waypoints,  # [K, 3]
    scene,
    index=None,
    box_margin: float = 0.1,
    *,
    max_split_depth: int = 4,
    min_overlap: float = 1e-3,
    margin: float = 1e-6,
    normal: str = "auto",
    exact_overlap: bool = False,
    box: str = "aabb",
    backend: str = "cpu",
    batch_scene=None,
    batch_index=None,
    grid=None,
    known=(),
    region=None,
    split_long: Optional[float] = None,
    threads: int = 1,
    merge: bool = False,
) -> Corridor:
    """Corridor of safe polytopes along a polyline of camera centres.

    waypoints: [K, 3] (K >= 2; repeated consecutive points are dropped). Returns a Corridor whose
    ``waypoints`` [M+1, 3] include any midpoints added by splitting (M >= K-1 segments).
    box_margin: each polytope lives in its segment's bounding box grown by this (scene units); larger
    boxes give the QP more room but cost more planes.
    min_overlap: junctions whose overlap (Chebyshev radius of P_m ∩ P_{m+1}) is below this are
    reported in ``thin_joints`` with a warning. exact_overlap: always solve the LP (else only when the
    cheap lower bound, the shared waypoint's distance to the nearest face of either polytope, is small).
    box: "aabb" (segment bounding box + margin, axis-aligned) or "oriented" (box aligned with the
    segment, margin on every side): far fewer candidate ellipsoids for long diagonal segments, so
    faster, but less room for the trajectory away from the segment.
    backend: "cpu" (one host ``safe_polytope`` per segment) or "batched" (``safe_polytopes_batched`` for
    all segments at once on ``batch_scene`` / ``batch_index``, default ``scene`` / ``index``, which must
    hold the same ellipsoids; flagged segments then take the host path with splitting; box "aabb" only).
    grid: optional grid_polytope.VoxelObstacles; segments lying in its free voxels get grid polytopes (module
    docstring), the rest go to the backend.
    known: safe polytopes (of this scene) built earlier, e.g. the one the goal was projected onto; a segment with
    both ends inside one of them (checked) takes it as its polytope, before the grid and the backend.
    region: (lo [3], hi [3]) the planning region; Corridor.constraints() cuts every polytope to it.
    split_long: with ``grid`` and box "aabb", long segments that need a Prop-2 polytope are split first (module
    docstring); None: never.
    threads: how many Prop-2 (host) polytopes may be built at once (host_pool.ordered_map: their compiled kernel
    releases the GIL); the same polytopes, in the same order, whatever the number.
    merge: consecutive segments one of whose polytopes holds both (with corridor_trim.MERGE_ROOM to spare) become one
    segment in that polytope (corridor_trim.merged_runs; host polytopes, corridors of corridor_trim.TABLE_MIN_SEGMENTS
    segments or more): the corridor's waypoints are then a
    subsequence of the path's (same first and last), M may be < K-1, and every polytope is one built for the path.
    Raises InvalidInputError (bad waypoints), CorridorError (a segment cannot be covered).
    """
    _check_options(box, box_margin, backend, split_long, threads)
    w = _prepared_waypoints(waypoints)
    kw = dict(margin=margin, normal=normal)
    stats = {"splits": 0}
    pre = _grid_polytopes([w], grid, box_margin, margin, box, scene.means.device, known, stats)[0]
    if split_long is not None and box == "aabb":
        w, pre = _split_long_segments(w, pre, grid, split_long, box_margin, margin, stats, scene.means.device)
    if backend == "batched":
        batched = _batched_polytopes([w], scene, index, box_margin, margin, normal, batch_scene, batch_index, [pre])[0]
        stats["host_segments"] = sum(p is None for p in batched)
    else:
        batched = pre
    pieces = _path_pieces(w, batched, scene, index, box_margin, max_split_depth, kw, stats, box, threads)
    out = _assemble(pieces, stats, min_overlap, exact_overlap, scene.means.device, merge)
    out.region = region
    return out


def build_corridors(waypoint_list, scene, index=None, **options) -> list:
    """build_corridor for several polylines (the candidates of one request): a list, in order, of a Corridor or
    the CorridorError that path raised. options: build_corridor's keyword arguments (box "aabb" only). With
    backend "batched" the safe polytopes of ALL their segments come from ONE safe_polytopes_batched call (one GPU
    computation for the whole request instead of one per candidate; each segment gets the polytope build_corridor
    would give it alone); flagged segments take the host path with splitting, per path."""
    defaults = {k: p.default for k, p in inspect.signature(build_corridor).parameters.items()
                if p.default is not inspect.Parameter.empty and k != "index"}
    unknown = set(options) - set(defaults)
    if unknown:
        raise InvalidInputError(f"build_corridors: unknown options {sorted(unknown)}")
    o = {**defaults, **options}
    if o["box"] != "aabb":
        raise InvalidInputError("build_corridors supports box='aabb' only")
    _check_options(o["box"], o["box_margin"], o["backend"], o["split_long"], o["threads"])
    ws = [_prepared_waypoints(wp) for wp in waypoint_list]
    kw = dict(margin=o["margin"], normal=o["normal"])
    counts = [{} for _ in ws]
    pre = _grid_polytopes(ws, o["grid"], o["box_margin"], o["margin"], "aabb", scene.means.device, o["known"], counts)
    if o["split_long"] is not None:
        split = [_split_long_segments(w, p, o["grid"], o["split_long"], o["box_margin"], o["margin"], c,
                                      scene.means.device)
                 for w, p, c in zip(ws, pre, counts)]
        ws, pre = [x[0] for x in split], [x[1] for x in split]
    if o["backend"] == "batched" and ws:
        batched = _batched_polytopes(ws, scene, index, o["box_margin"], o["margin"], o["normal"], o["batch_scene"],
                                     o["batch_index"], pre)
    else:
        batched = pre
    out: list = []
    for w, bp, cnt in zip(ws, batched, counts):
        stats = {"splits": 0, "host_segments": sum(p is None for p in bp) if o["backend"] == "batched" else 0, **cnt}
        try:
            pieces = _path_pieces(w, bp, scene, index, o["box_margin"], o["max_split_depth"], kw, stats, "aabb",
                                  o["threads"])
        except CorridorError as e:
            out.append(e)
            continue
        cor = _assemble(pieces, stats, o["min_overlap"], o["exact_overlap"], scene.means.device, o["merge"])
        cor.region = o["region"]
        out.append(cor)
    return out


def _check_options(box: str, box_margin: float, backend: str, split_long: Optional[float] = None,
                   threads: int = 1) -> None:
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise InvalidInputError(f"threads must be an integer >= 1, got {threads!r}")
    if split_long is not None and not (math.isfinite(float(split_long)) and float(split_long) > 0):
        raise InvalidInputError(f"split_long must be None or a finite length > 0, got {split_long}")
    if box not in ("aabb", "oriented"):
        raise InvalidInputError(f"box must be 'aabb' or 'oriented', got {box!r}")
    if not (math.isfinite(float(box_margin)) and float(box_margin) > 0):
        raise InvalidInputError(f"box_margin must be a finite length > 0, got {box_margin}")
    if backend not in ("cpu", "batched"):
        raise InvalidInputError(f"corridor backend must be 'cpu' or 'batched', got {backend!r}")
    if backend == "batched" and box != "aabb":
        raise InvalidInputError("the batched corridor backend supports box='aabb' only")


def _prepared_waypoints(waypoints) -> np.ndarray:
    """Waypoints [M+1, 3] as float64 numpy on the host, repeated consecutive points dropped; InvalidInputError if
    unusable. The corridor works on host copies of its few points: per-segment torch calls on 3-vectors cost more
    than the grid polytopes they feed."""
    if isinstance(waypoints, Tensor):
        w = waypoints.detach().to("cpu", torch.float64).numpy()
    else:
        try:
            w = np.asarray(waypoints, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise InvalidInputError(f"build_corridor needs waypoints [K>=2, 3] of numbers: {e}") from None
    if w.ndim != 2 or w.shape[-1] != 3 or w.shape[0] < 2:
        raise InvalidInputError(f"build_corridor needs waypoints [K>=2, 3], got {tuple(w.shape)}")
    if not np.isfinite(w).all():
        raise InvalidInputError("build_corridor: waypoints contain NaN/inf")
    keep = np.ones(w.shape[0], dtype=bool)
    keep[1:] = np.sqrt(((w[1:] - w[:-1]) ** 2).sum(-1)) > 1e-12
    if keep.all():  # the usual case: no copy
        return w
    w = w[keep]
    if w.shape[0] < 2:
        raise InvalidInputError("build_corridor: all waypoints coincide (start == goal?)")
    return w


def _known_polytope(known, a: np.ndarray, b: np.ndarray, dev):
    """The first of the ``known`` polytopes that holds both ends of the segment a -> b (float64 numpy [3]; so the
    whole segment), on ``dev``, or None."""
    for p in known:
        pa = p if p.A.device == dev else p.to(dev)
        got = pa.host_arrays()
        if got is not None:
            A, c = got
            inside = bool((A @ a <= c).all()) and bool((A @ b <= c).all())
        else:
            inside = bool(pa.contains(torch.from_numpy(np.stack([a, b])).to(dev)).all())
        if inside:
            return pa
    return None


def _grid_polytopes(ws, grid, box_margin, margin, box, dev, known=(), stats=None) -> list:
    """Per path (waypoints [M+1, 3] float64 numpy), [Polytope | None] per segment, on ``dev``: a ``known`` polytope
    holding the segment, else the grid polytope of a segment that lies in free voxels of ``grid`` (None: neither;
    the segment needs an exact polytope). stats: a dict (one path) or a list of dicts (one per path) that get the
    counts ``known_segments`` and ``grid_segments``. A path's grid polytopes come from one VoxelObstacles.polytopes
    call (one compiled call for all its segments: per segment, the call's Python glue cost about as much as the
    ~20 us polytope itself)."""
    out = []
    for k, w in enumerate(ws):
        st = (stats[k] if isinstance(stats, list) else stats) if stats is not None else {}
        st.setdefault("known_segments", 0)
        st.setdefault("grid_segments", 0)
        M = w.shape[0] - 1
        row = [_known_polytope(known, w[i], w[i + 1], dev) for i in range(M)] if known else [None] * M
        st["known_segments"] += sum(p is not None for p in row)
        if grid is not None and box == "aabb":
            got = grid.polytopes(w, box_margin, margin, skip=[p is not None for p in row], device=dev)
            st["grid_segments"] += sum(p is not None for p in got)
            row = [p if p is not None else g for p, g in zip(row, got)]
        out.append(row)
    return out


def _free_pieces(a: np.ndarray, b: np.ndarray, grid, split_long: float, depth: int = 0) -> list:
    """[(p0, p1, free)] covering the segment a -> b [3] in order: bisected (exact midpoints) until each piece lies in
    free voxels of ``grid`` or is no longer than ``split_long`` (at most 12 levels)."""
    free = bool(grid.segments_free(a[None], b[None])[0])
    if free or depth >= 12 or float(np.linalg.norm(b - a)) <= split_long:
        return [(a, b, free)]
    mid = 0.5 * (a + b)
    return _free_pieces(a, mid, grid, split_long, depth + 1) + _free_pieces(mid, b, grid, split_long, depth + 1)


def _merged_runs(pieces: list) -> list:
    """_free_pieces' pieces grouped: each run of consecutive free pieces is one group, every other piece its own;
    [[(p0, p1, free)]] in order."""
    out: list = []
    for q in pieces:
        if q[2] and out and out[-1][-1][2]:
            out[-1].append(q)
        else:
            out.append([q])
    return out


def _long_pieces(a: np.ndarray, b: np.ndarray, grid, split_long, box_margin, margin, dev) -> list:
    """[(p0, p1, Polytope | None)] for a long segment a -> b that needs a Prop-2 polytope: each run of free pieces gets
    one grid polytope (a run whose merged polytope fails its check gets its pieces' ones), other pieces None."""
    out = []
    for run in _merged_runs(_free_pieces(a, b, grid, split_long)):
        p0, p1, free = run[0][0], run[-1][1], run[0][2]
        poly = grid.polytope(p0, p1, box_margin, margin, device=dev) if free else None
        if free and poly is None and len(run) > 1:
            out += [(q0, q1, grid.polytope(q0, q1, box_margin, margin, device=dev)) for q0, q1, _ in run]
        else:
            out.append((p0, p1, poly))
    return out


def _split_long_segments(w: np.ndarray, pre: list, grid, split_long: float, box_margin: float, margin: float,
                         stats: dict, dev) -> tuple:
    """(waypoints [M'+1, 3] float64 numpy, [Polytope | None] per segment): w [M+1, 3] and its pre-built polytopes
    ``pre`` with each segment longer than ``split_long`` that has none split by _long_pieces (stats["long_pieces"]:
    segments added); new polytopes on ``dev``."""
    stats.setdefault("long_pieces", 0)
    if grid is None or not any(p is None for p in pre):
        return w, pre
    pts, polys = [w[0]], []
    for m, p in enumerate(pre):
        if p is not None or float(np.linalg.norm(w[m + 1] - w[m])) <= split_long:
            pts.append(w[m + 1])
            polys.append(p)
            continue
        parts = _long_pieces(w[m], w[m + 1], grid, split_long, box_margin, margin, dev)
        for k, (_, q1, q) in enumerate(parts):
            pts.append(w[m + 1] if k == len(parts) - 1 else q1)
            polys.append(q)
        stats["long_pieces"] += len(parts) - 1
    return np.stack(pts), polys


def _batched_polytopes(ws, scene, index, box_margin, margin, normal, batch_scene, batch_index, pre=None) -> list:
    """Per path, [Polytope | None] per segment (None: flagged, the host path decides it) from one
    safe_polytopes_batched call over the segments of every path ws[i] [M_i+1, 3] (float64 numpy) that have no
    polytope in ``pre``
    yet (per path, [Polytope | None] per segment; those given are kept as they are)."""
    dev = scene.means.device
    bscene = scene if batch_scene is None else batch_scene
    bindex = index if batch_scene is None and batch_index is None else batch_index
    pre = [[None] * (w.shape[0] - 1) for w in ws] if pre is None else pre
    out = [list(p) for p in pre]
    todo = [(i, m) for i, p in enumerate(pre) for m, q in enumerate(p) if q is None]
    if not todo:
        return out
    bws = [torch.from_numpy(w).to(bscene.means.device) for w in ws]
    segs = torch.stack([torch.stack([bws[i][m], bws[i][m + 1]]) for i, m in todo])  # [T, 2, 3]
    lo = torch.minimum(segs[:, 0], segs[:, 1]) - box_margin  # [T, 3] same boxes as the host path
    hi = torch.maximum(segs[:, 0], segs[:, 1]) + box_margin
    polys_b, _ = safe_polytopes_batched(segs, bscene, bindex, lo, hi, margin=margin, normal=normal, out_device=dev)
    for (i, m), p in zip(todo, polys_b):
        out[i][m] = p
    return out


def _path_pieces(w, batched, scene, index, box_margin, max_split_depth, kw, stats, box, threads: int = 1) -> list:
    """(polytope, p0, p1) per segment of the path w [M+1, 3] (float64 numpy; p0, p1 its rows or midpoints between
    them): the polytope already built for it (grid or batched)
    where there is one, else the host path (SeedNotFreeError -> split, as with backend "cpu"); up to ``threads``
    host segments are built at once (host_pool.ordered_map), and a CorridorError is that of the first failing
    segment, as in a serial loop."""
    todo = [m for m in range(w.shape[0] - 1) if batched[m] is None]
    one = {}  # serial, axis-aligned boxes: one compiled call for all of them (None: that segment's own path)
    if threads <= 1 and box == "aabb" and todo:
        one = dict(zip(todo, aabb_polytopes([(w[m], w[m + 1]) for m in todo], scene, index, box_margin, **kw)))

    def host(m):
        if one.get(m) is not None:
            return [(one[m], w[m], w[m + 1])], 0
        got, st = [], {"splits": 0}
        _segment_polytopes(w[m], w[m + 1], scene, index, box_margin, 0, max_split_depth, kw, got, st, m, box)
        return got, st["splits"]

    built = dict(zip(todo, ordered_map(host, todo, threads)))
    pieces: list = []
    for m in range(w.shape[0] - 1):
        if batched[m] is not None:
            pieces.append((batched[m], w[m], w[m + 1]))
        else:
            got, splits = built[m]
            pieces += got
            stats["splits"] += splits
    return pieces


OVERLAP_PROBE_STEPS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)  # x min_overlap: how far the probes go from the junction


def _probed_overlap(p0: Polytope, p1: Polytope, w_prev: Tensor, wj: Tensor, w_next: Tensor,
                    min_overlap: float) -> float:
    """A lower bound of the Chebyshev radius of p0 ∩ p1 (both hold the junction wj [3]) without an LP: the largest
    min over both polytopes' faces of (b - a.c) / |a| at probe points c = wj + t d, d along the two segments, their
    sum, and away from the faces nearly tight at wj (each such value is the radius of a ball at c inside both).
    The LP (chebyshev_center, ~1.2-2 ms of HiGHS set-up on the CPU box) is then only needed when no probe shows
    min_overlap of room."""
    A = torch.cat([p0.A, p1.A])  # [F, 3]
    b = torch.cat([p0.b, p1.b])
    norms = A.norm(dim=-1).clamp_min(1e-300)
    dirs = [w_prev - wj, w_next - wj]
    dirs = [d / d.norm().clamp_min(1e-300) for d in dirs]
    dirs.append(dirs[0] + dirs[1])
    tight = (b - A @ wj) / norms < 2.0 * min_overlap
    away = -(A[tight] / norms[tight, None]).sum(0)
    dirs += [away, away + dirs[0], away + dirs[1], away + dirs[2]]
    D = torch.stack(dirs)
    D = D / D.norm(dim=-1, keepdim=True).clamp_min(1e-300)  # [8, 3] (a zero direction stays zero: c = wj)
    t = torch.as_tensor(OVERLAP_PROBE_STEPS, dtype=A.dtype, device=A.device) * min_overlap
    c = wj + (t[:, None, None] * D[None]).reshape(-1, 3)  # [T * 8, 3]
    return float(((b - c @ A.T) / norms).min(dim=-1).values.max())


def _host_junctions(pieces, planes: list, merge: bool, stats: dict):
    """(pieces, the junctions' lower bounds [M-1] of the overlap radius) for CPU polytopes (planes: their
    Polytope.host_arrays, in order), from one slack table of
    every polytope at every waypoint (corridor_trim.slack_table: a junction's bound is the smaller distance of its
    waypoint inside the two polytopes); ``merge`` (float64 planes): the pieces merged first (corridor_trim.merged_runs,
    stats["merged"]). (pieces, None) when the table does not apply. Below corridor_trim.TABLE_MIN_SEGMENTS pieces:
    the bounds junction by junction (the same values), nothing merged."""
    if len(pieces) < TABLE_MIN_SEGMENTS:  # a few junctions: one by one, nothing merged
        return pieces, [float(min((b0 - a0 @ x).min(), (b1 - a1 @ x).min()))
                        for (a0, b0), (a1, b1), (_, _, x) in zip(planes[:-1], planes[1:], pieces[:-1])]
    w = np.stack([pieces[0][1]] + [p1 for _, _, p1 in pieces])  # [M+1, 3]
    slack = slack_table(planes, w)
    if slack is None:
        return pieces, None
    m = len(pieces)
    if merge and all(a.dtype == np.float64 and b.dtype == np.float64 for a, b in planes):
        runs = merged_runs(slack, MERGE_ROOM)
        stats["merged"] = m - len(runs)
        pieces = [(pieces[i][0], pieces[s][1], pieces[e - 1][2]) for i, s, e in runs]
    else:
        runs = [(k, k, k + 1) for k in range(m)]
    poly, end = np.array([r[0] for r in runs]), np.array([r[2] for r in runs])
    return pieces, np.minimum(slack[poly[:-1], end[:-1]], slack[poly[1:], end[:-1]]).tolist()


def _assemble(pieces, stats, min_overlap: float, exact_overlap: bool, dev, merge: bool = False) -> Corridor:
    """The Corridor of a path's pieces (waypoints float64 numpy), with the junctions' overlap radii (thin ones warned
    about); its waypoints on ``dev``. ``merge``: consecutive pieces merged first (corridor_trim.merged_runs) when
    every polytope is on the host."""
    lbs = None
    planes = [p.host_arrays() for p, _, _ in pieces] if torch.device(dev).type == "cpu" else [None]
    if all(h is not None for h in planes):
        # the junctions' slacks in numpy on the CPU, all at once (per junction, ~8 torch calls on [F]-vectors cost
        # ~30 us, and numpy per junction a tenth of that)
        pieces, lbs = _host_junctions(pieces, planes, merge, stats)
    polys = [p for p, _, _ in pieces]
    wps = torch.from_numpy(np.stack([pieces[0][1]] + [p1 for _, _, p1 in pieces]))  # [M+1, 3]
    if torch.device(dev).type != "cpu":
        wps = wps.to(dev)

    radii = []
    thin = []
    for m in range(len(polys) - 1):
        if lbs is not None and lbs[m] >= min_overlap and not exact_overlap:  # the usual junction: room enough
            radii.append(lbs[m])
            continue
        wj = wps[m + 1]
        lb = lbs[m] if lbs is not None else float(torch.minimum(polys[m].slack(wj), polys[m + 1].slack(wj)))
        if lb < min_overlap and not exact_overlap:
            lb = max(lb, _probed_overlap(polys[m], polys[m + 1], wps[m], wj, wps[m + 2], min_overlap))
        rad = lb
        if exact_overlap or lb < min_overlap:
            A = torch.cat([polys[m].A, polys[m + 1].A])
            b = torch.cat([polys[m].b, polys[m + 1].b])
            _, rad = chebyshev_center(A, b)
            rad = max(rad, lb)
        radii.append(rad)
        if rad < min_overlap:
            thin.append(m)
    if thin:
        warnings.warn(
            f"corridor: {len(thin)} junction(s) have little room (overlap radius < {min_overlap:g}) at "
            f"waypoints {[m + 1 for m in thin]}; the trajectory may slow down there",
            stacklevel=3,
        )
    return Corridor(
        polytopes=polys,
        waypoints=wps,
        overlap_radius=torch.tensor(radii, dtype=torch.float64),
        thin_joints=thin,
        n_splits=stats["splits"],
        n_host_segments=stats.get("host_segments", 0),
        n_grid_segments=stats.get("grid_segments", 0),
        n_known_segments=stats.get("known_segments", 0),
        n_long_pieces=stats.get("long_pieces", 0),
        n_merged=stats.get("merged", 0),
    )
