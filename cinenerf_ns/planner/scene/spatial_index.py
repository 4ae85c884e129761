"""Uniform-grid buckets of ellipsoid bounding boxes, so no query scans all N ellipsoids.

Layout: a small hierarchy of dense uniform grids (cell sizes c, 2c, 4c, ...) sharing one origin.
Each ellipsoid's padded AABB goes into the finest level where it spans at most ``max_span`` cells
per axis, so a huge ellipsoid lands in a coarse level (few cells) instead of being copied into
thousands of fine cells. Every level is CSR (``offsets[C+1]``, ``ids[M]``) in torch, so the same code
runs on CPU and CUDA.

Guarantee (tested against brute force): a query returns EXACTLY the ellipsoids whose padded AABB
meets the query box; candidates come from the grid, then an exact AABB-overlap filter. AABBs are
held in float64 and grown by a relative epsilon so rounding can only add candidates, never drop one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, List, Optional, Tuple, Union

import torch
from torch import Tensor

from ..errors import InvalidInputError
from .ellipsoids import EllipsoidScene

if TYPE_CHECKING:  # numpy is imported where it is used (morton_order); the annotation only names it
    import numpy as np

SCAN_CELLS_PER_TEST = 8  # query_points scans all N boxes once the grid lookup would visit this many cells per test


@dataclass
class _Level:
    cell: float  # edge length of a cell
    dims: Tensor  # [3] long, number of cells per axis
    offsets: Tensor  # [C+1] long, CSR row pointers (cell -> range in ids)
    ids: Tensor  # [M] long, ellipsoid ids bucketed by cell
    n_items: int  # ellipsoids stored in this level


SORT_DEDUPE_RATIO = 64  # query_box_in_planes sorts its listed entries when they are fewer than N / this, else flags N


def _spread_bits_21(v):
    """uint64 numpy [N] holding 21-bit integers -> the same bits moved to every third position (bit i -> 3 i)."""
    import numpy as np

    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def morton_order(points) -> "np.ndarray":
    """Permutation int64 [N] that sorts points [N, 3] (finite) along a Z-order (Morton) curve of a 2^21 grid over
    their bounding box: points close in space get close positions, so arrays stored in this order are read with
    few cache misses by a query that visits one region (polytope.py's compiled gather)."""
    import numpy as np

    p = np.asarray(points.detach().cpu().double() if isinstance(points, Tensor) else points, dtype=np.float64)
    if p.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-300) * float(2**21 - 1)).astype(np.uint64)  # [N, 3] in [0, 2^21)
    code = _spread_bits_21(q[:, 0]) | (_spread_bits_21(q[:, 1]) << np.uint64(1))
    code |= _spread_bits_21(q[:, 2]) << np.uint64(2)
    return np.argsort(code, kind="stable").astype(np.int64)


def _cell_of(x: Tensor, origin: Tensor, cell: float, dims: Tensor) -> Tensor:
    """Cell coordinates (clamped to the grid) of positions x [..., 3] -> long [..., 3]."""
    c = torch.floor((x - origin) / cell)
    c = torch.minimum(torch.clamp_min(c, 0), (dims - 1).to(c.dtype))
    return c.long()


def _expand_ranges(counts: Tensor) -> Tuple[Tensor, Tensor]:
    """For counts [K] -> (owner [sum], local [sum]): owner[j] = k, local[j] = 0..counts[k]-1."""
    ends = torch.cumsum(counts, 0)  # [K]
    total = int(ends[-1]) if counts.numel() else 0
    # searchsorted instead of repeat_interleave: the latter is pathologically slow on CPU here.
    pos = torch.arange(total, device=counts.device)
    owner = torch.searchsorted(ends, pos, right=True)
    local = pos - (ends - counts).index_select(0, owner)
    return owner, local


class GridIndex:
    """Bucket grid over the ellipsoids' AABBs grown by ``pad`` (default: the camera radius)."""

    def __init__(self, lo: Tensor, hi: Tensor, origin: Tensor, levels: List[_Level], pad: float) -> None:
        self.lo = lo  # [N, 3] float64 padded AABB lower corners
        self.hi = hi  # [N, 3] float64 padded AABB upper corners
        self.boxes = torch.cat([lo, hi], -1)  # [N, 6] the same, one row per ellipsoid (one gather)
        self.origin = origin  # [3] float64
        self.levels = levels
        self.pad = float(pad)

    # ------------------------------------------------------------------ build
    @classmethod
    def build(
        cls,
        scene: EllipsoidScene,
        cell_size: Optional[float] = None,
        pad: Optional[float] = None,
        max_span: int = 3,
        max_cells: int = 2_000_000,
    ) -> "GridIndex":
        """Index ``scene``. ``pad`` grows every AABB (default ``scene.camera_radius``); ``cell_size``
        defaults to 0.75 x the median padded-AABB extent (bounded so the finest level has <= ``max_cells``)."""
        pad = scene.camera_radius if pad is None else float(pad)
        if not (math.isfinite(pad) and pad >= 0):
            raise InvalidInputError(f"GridIndex pad must be finite and >= 0, got {pad}")
        mu = scene.means.double()
        h = torch.sqrt(((scene.rotations.double() * scene.radii.double()[:, None, :]) ** 2).sum(-1))
        # Relative epsilon: float rounding may only enlarge the boxes (never miss a candidate).
        h = h * (1 + 1e-9) + pad + 1e-12 * (1 + mu.abs().max(-1, keepdim=True).values)
        lo, hi = mu - h, mu + h
        if len(scene) == 0:
            raise InvalidInputError("cannot index an empty scene")
        origin = lo.min(0).values
        extent = (hi.max(0).values - origin).clamp_min(1e-9)  # [3]
        if cell_size is None:
            # 0.75 x the median padded extent: smaller cells only add build time and entries, larger ones slow
            # the queries (docs/PLANNER_DEFAULTS.md)
            cell_size = 0.75 * float((hi - lo).max(-1).values.median())
            vol_cells = float(extent.prod()) / cell_size**3
            if vol_cells > max_cells:
                cell_size *= (vol_cells / max_cells) ** (1 / 3)
        cell_size = float(cell_size)
        if not (math.isfinite(cell_size) and cell_size > 0):
            raise InvalidInputError(f"GridIndex cell_size must be finite and > 0, got {cell_size}")
        levels: List[_Level] = []
        remaining = torch.arange(len(scene), device=mu.device)
        c = cell_size
        while True:
            dims = (torch.floor(extent / c).long() + 1).clamp_min(1)
            top = bool((dims <= max_span).all())
            clo = _cell_of(lo[remaining], origin, c, dims)
            chi = _cell_of(hi[remaining], origin, c, dims)
            span = chi - clo + 1  # [R, 3]
            fits = torch.ones_like(remaining, dtype=torch.bool) if top else (span <= max_span).all(-1)
            sel = remaining[fits]
            clo, span = clo[fits], span[fits]
            owner, local = _expand_ranges(span.prod(-1))
            sz, sy = span[owner, 2], span[owner, 1]
            d = torch.stack([local // (sz * sy), (local // sz) % sy, local % sz], -1)
            cells = clo[owner] + d
            lin = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
            order = torch.sort(lin.int() if int(dims.prod()) < 2**31 else lin).indices
            n_cells = int(dims.prod())
            counts = torch.bincount(lin, minlength=n_cells)
            offsets = torch.zeros(n_cells + 1, dtype=torch.long, device=mu.device)
            offsets[1:] = torch.cumsum(counts, 0)
            levels.append(_Level(cell=c, dims=dims, offsets=offsets, ids=sel[owner[order]], n_items=int(sel.numel())))
            remaining = remaining[~fits]
            if remaining.numel() == 0:
                break
            c *= 2.0
        return cls(lo, hi, origin, levels, pad)

    def __len__(self) -> int:
        return int(self.lo.shape[0])

    @property
    def device(self) -> torch.device:
        return self.lo.device

    def to(self, device: Union[str, torch.device]) -> "GridIndex":
        lv = [_Level(l.cell, l.dims.to(device), l.offsets.to(device), l.ids.to(device), l.n_items) for l in self.levels]
        return GridIndex(self.lo.to(device), self.hi.to(device), self.origin.to(device), lv, self.pad)

    def stats(self) -> dict:
        """Sizes, for logs and benchmarks."""
        return {
            "n": len(self),
            "pad": self.pad,
            "levels": [
                {"cell": l.cell, "dims": l.dims.tolist(), "items": l.n_items, "entries": int(l.ids.numel())}
                for l in self.levels
            ],
        }

    # ------------------------------------------------------------------ queries
    def query_boxes(self, qlo: Tensor, qhi: Tensor, method: str = "grid") -> Tuple[Tensor, Tensor]:
        """Pairs (box_idx [K], g_idx [K]), sorted by box, of every ellipsoid whose padded AABB meets
        box q = [qlo[q], qhi[q]] (closed boxes). qlo, qhi: [Q, 3].

        method: "grid" (bucket lookup; within a box the ids come in bucket order), "scan" (the closed-box test
        of every query box against all N boxes, blocked; ids ascending within a box: far fewer kernels and no
        duplicate entries to filter, so cheaper once the boxes together visit a good fraction of Q x N entries,
        e.g. the big boxes of a whole path's corridor) or "auto" (scan when the grid lookup's estimated entries
        reach ``Q * N / 8``). All return the same set of pairs."""
        qlo = torch.as_tensor(qlo, device=self.device).double().reshape(-1, 3)
        qhi = torch.as_tensor(qhi, device=self.device).double().reshape(-1, 3)
        if qlo.shape != qhi.shape:
            raise InvalidInputError(f"query box corners disagree: {tuple(qlo.shape)} vs {tuple(qhi.shape)}")
        if method not in ("auto", "grid", "scan"):
            raise InvalidInputError(f"query_boxes method must be 'auto', 'grid' or 'scan', got {method!r}")
        if not (torch.isfinite(qlo).all() and torch.isfinite(qhi).all()):
            raise InvalidInputError("query boxes contain NaN or inf")
        if method == "auto":
            method = "scan" if self._estimated_entries_boxes(qlo, qhi) >= qlo.shape[0] * len(self) / 8 else "grid"
        if method == "scan":
            return self._scan_boxes(qlo, qhi)
        qbox = torch.cat([qlo, qhi], -1)  # [Q, 6]
        out_q, out_g = [], []
        for lv in self.levels:
            grid_hi = self.origin + lv.dims.double() * lv.cell
            inside = ((qhi >= self.origin) & (qlo <= grid_hi) & (qhi >= qlo)).all(-1)  # [Q]
            clo = _cell_of(qlo, self.origin, lv.cell, lv.dims)
            chi = _cell_of(qhi, self.origin, lv.cell, lv.dims)
            span = (chi - clo + 1) * inside[:, None]
            qo, local = _expand_ranges(span.prod(-1))
            sz, sy = span[qo, 2], span[qo, 1]
            cells = clo[qo] + torch.stack([local // (sz * sy), (local // sz) % sy, local % sz], -1)  # [Cq, 3]
            lin = (cells[:, 0] * lv.dims[1] + cells[:, 1]) * lv.dims[2] + cells[:, 2]
            start = lv.offsets[lin]
            owner, k = _expand_ranges(lv.offsets[lin + 1] - start)
            g = lv.ids.index_select(0, start.index_select(0, owner) + k)
            q = qo.index_select(0, owner)
            gb = self.boxes.index_select(0, g)  # [K, 6] padded AABBs of the candidates
            qb = qbox.index_select(0, q)  # [K, 6]
            hit = (gb[:, :3] <= qb[:, 3:]).all(-1) & (gb[:, 3:] >= qb[:, :3]).all(-1)
            owner, g, q, gb = owner[hit], g[hit], q[hit], gb[hit]
            # Dedupe without sorting: a pair is kept only in the first cell (per axis) shared by the
            # query's cell range and the ellipsoid's cell range.
            g_lo_cell = _cell_of(gb[:, :3], self.origin, lv.cell, lv.dims)
            hit = (cells.index_select(0, owner) == torch.maximum(g_lo_cell, clo.index_select(0, q))).all(-1)
            out_q.append(q[hit])
            out_g.append(g[hit])
        q = torch.cat(out_q)
        g = torch.cat(out_g)
        order = torch.argsort(q, stable=True)
        return q[order], g[order]

    def _scan_boxes(self, qlo: Tensor, qhi: Tensor, max_elems: int = 1 << 25) -> Tuple[Tensor, Tensor]:
        """query_boxes by brute force: the same closed-box test against all N padded AABBs, in blocks of
        boxes so that a block's [B, N] masks stay below ``max_elems`` entries. Sorted by box, then id."""
        n = len(self)
        if not hasattr(self, "_cols"):  # per-axis contiguous columns [6, N]: each test reads one column
            self._cols = self.boxes.T.contiguous()
        cols = self._cols
        ok = (qhi >= qlo).all(-1)  # [Q] an inverted box meets nothing (as in the grid lookup)
        step = max(1, max_elems // max(n, 1))
        out_q, out_g = [], []
        for s in range(0, qlo.shape[0], step):
            lo_b, hi_b = qlo[s:s + step], qhi[s:s + step]  # [B, 3]
            hit = ok[s:s + step, None].expand(-1, n).clone()  # [B, N]
            for a in range(3):
                hit &= cols[a][None, :] <= hi_b[:, a:a + 1]
                hit &= cols[3 + a][None, :] >= lo_b[:, a:a + 1]
            qi, gi = torch.nonzero(hit, as_tuple=True)  # row-major: sorted by box, then id
            out_q.append(qi + s)
            out_g.append(gi)
        return torch.cat(out_q), torch.cat(out_g)

    def _estimated_entries_boxes(self, qlo: Tensor, qhi: Tensor) -> float:
        """Sum over boxes [Q, 3] of _estimated_entries (one host sync)."""
        est = torch.zeros((), dtype=torch.float64, device=self.device)
        for lv in self.levels:
            est = est + self._cells_spanned(qlo, qhi, lv).sum() * (lv.ids.numel() / max(1, int(lv.dims.prod())))
        return float(est)

    def _cells_spanned(self, qlo: Tensor, qhi: Tensor, lv: "_Level") -> Tensor:
        """Cells [Q] of level ``lv`` that each box [Q, 3] spans (clipped to the grid's size per axis)."""
        span = (torch.floor((qhi - self.origin) / lv.cell) - torch.floor((qlo - self.origin) / lv.cell) + 1)
        return torch.minimum(span.clamp_min(0), lv.dims.to(span.dtype)).prod(-1)

    def query_box(self, lo: Tensor, hi: Tensor, method: str = "auto") -> Tensor:
        """Ids [K] (ascending) of the ellipsoids whose padded AABB meets the box [lo, hi].

        method: "grid" (bucket lookup), "scan" (one vectorised AABB test over all N boxes: cheaper
        than the lookup once the box spans so many cells that it would visit >= N/2 entries, e.g. the
        big boxes of corridor polytopes in dense scenes) or "auto" (picks by that estimate). Both
        return exactly the same ids (same closed-box test)."""
        lo = torch.as_tensor(lo, device=self.device).double().reshape(1, 3)
        hi = torch.as_tensor(hi, device=self.device).double().reshape(1, 3)
        if method not in ("auto", "grid", "scan"):
            raise InvalidInputError(f"query_box method must be 'auto', 'grid' or 'scan', got {method!r}")
        if method == "auto":
            method = "scan" if self._estimated_entries(lo[0], hi[0]) >= 0.5 * len(self) else "grid"
        if method == "scan":
            hit = (self.lo <= hi).all(-1) & (self.hi >= lo).all(-1)  # [N]
            if not bool(torch.isfinite(lo).all() and torch.isfinite(hi).all()):
                raise InvalidInputError("query boxes contain NaN or inf")
            return torch.nonzero(hit & (hi >= lo).all(-1)).squeeze(-1)
        _, g = self.query_boxes(lo, hi)
        return torch.sort(g).values

    def _estimated_entries(self, lo: Tensor, hi: Tensor) -> float:
        """Rough number of bucket entries a grid lookup of box [lo, hi] visits (mean entries per
        cell x cells spanned, per level); only used to choose the query method."""
        est = 0.0
        for lv in self.levels:
            span = (torch.floor((hi - self.origin) / lv.cell) - torch.floor((lo - self.origin) / lv.cell) + 1)
            span = torch.minimum(span.clamp_min(0), lv.dims.to(span.dtype))
            est += float(span.prod()) * lv.ids.numel() / max(1, int(lv.dims.prod()))
        return est

    def query_points(self, points: Tensor, radius: Union[float, Tensor] = 0.0) -> Tuple[Tensor, Tensor]:
        """Candidate pairs (pt_idx [K], g_idx [K]), sorted by point: every ellipsoid whose padded AABB
        (grown by ``self.pad``) meets the cube of half-width ``radius`` (scalar or [P]) around the point.

        Hence any ellipsoid within Euclidean distance ``radius + pad`` of a point is returned."""
        points = torch.as_tensor(points, device=self.device).double().reshape(-1, 3)
        rad = torch.as_tensor(radius, device=self.device).double()
        if rad.ndim == 0:
            rad = rad.expand(points.shape[0])
        if rad.shape != (points.shape[0],) or bool((rad < 0).any()) or not bool(torch.isfinite(rad).all()):
            raise InvalidInputError(f"query radius must be finite, >= 0, scalar or [P]; got shape {tuple(rad.shape)}")
        qlo, qhi = points - rad[:, None], points + rad[:, None]
        # the grid lookup visits every cell of every box: when the boxes are large next to the cells (a growing
        # search far from a scene of tiny ellipsoids), the scan's Q x N box tests are far cheaper; same pairs
        method = "scan" if self._visited_cells(qlo, qhi) > SCAN_CELLS_PER_TEST * qlo.shape[0] * len(self) else "grid"
        return self.query_boxes(qlo, qhi, method=method)

    def _visited_cells(self, qlo: Tensor, qhi: Tensor) -> float:
        """Cells the grid lookup of boxes [Q, 3] would visit, over all levels (one host sync)."""
        return float(sum(self._cells_spanned(qlo, qhi, lv).sum() for lv in self.levels))

    def query_box_in_planes(self, lo: Tensor, hi: Tensor, A: Tensor, b: Tensor, max_cells: int = 4_000_000) -> Tensor:
        """Ids [K] (ascending) of ellipsoids whose padded AABB meets the box [lo, hi]; every ellipsoid
        whose padded AABB meets [lo, hi] ∩ {x : A x <= b} is among them (A [F, 3], b [F]).

        Grid cells lying entirely beyond one plane (min over the cell of A_f.x > b_f) are not visited.
        Sound: a point x of AABB_g ∩ box ∩ P lies in a cell of g's level within the box's cell range
        that lists g and is not culled (it holds x, and A x <= b). Cells are grown by a relative
        epsilon before the test, so rounding can only keep a cell. Ellipsoids listed only in culled
        cells may still be returned (the result is a superset). Falls back to ``query_box`` (no
        culling) when the box spans more than ``max_cells`` cells of a level."""
        lo = torch.as_tensor(lo, device=self.device).double().reshape(3)
        hi = torch.as_tensor(hi, device=self.device).double().reshape(3)
        A = torch.as_tensor(A, device=self.device).double().reshape(-1, 3)  # [F, 3]
        b = torch.as_tensor(b, device=self.device).double().reshape(-1)  # [F]
        if A.shape[0] != b.shape[0]:
            raise InvalidInputError(f"plane normals [F, 3] and offsets [F] disagree: {tuple(A.shape)} vs "
                                    f"{tuple(b.shape)}")
        if not bool(torch.isfinite(lo).all() & torch.isfinite(hi).all() & torch.isfinite(A).all()
                    & torch.isfinite(b).all()):
            raise InvalidInputError("query box or planes contain NaN or inf")
        out = []
        for lv in self.levels:
            clo = _cell_of(lo, self.origin, lv.cell, lv.dims)  # [3]
            chi = _cell_of(hi, self.origin, lv.cell, lv.dims)  # [3]
            c0, c1 = torch.stack([clo, chi]).tolist()  # one host sync per level: [3], [3]
            if math.prod(h - l + 1 for l, h in zip(c0, c1)) > max_cells:
                return self.query_box(lo, hi)
            ax = [torch.arange(c0[i], c1[i] + 1, device=self.device) for i in range(3)]
            cells = torch.stack(torch.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)  # [C, 3]
            cmin = self.origin + cells.double() * lv.cell  # [C, 3]
            half = 0.5 * lv.cell * (1 + 1e-7) + 1e-12 * (1 + self.origin.abs().max()
                                                         + cmin.abs().max(-1, keepdim=True).values)
            centre = cmin + 0.5 * lv.cell  # [C, 3]
            low = centre @ A.T - half * A.abs().sum(-1)  # [C, F] min of A_f.x over the (grown) cell
            culled = (low > b + 1e-12 * (1 + b.abs())).any(-1)  # [C]
            cells = cells[~culled]
            lin = (cells[:, 0] * lv.dims[1] + cells[:, 1]) * lv.dims[2] + cells[:, 2]
            start = lv.offsets[lin]
            owner, k = _expand_ranges(lv.offsets[lin + 1] - start)
            out.append(lv.ids.index_select(0, start.index_select(0, owner) + k))
        # dedupe (an ellipsoid is listed in every cell its AABB meets): a flag per ellipsoid is cheaper than
        # sorting the listed entries when they are many; a few (a small box in a big scene) are cheaper to sort
        # than N flags to clear and scan
        entries = torch.cat(out)
        if entries.numel() * SORT_DEDUPE_RATIO < len(self):
            g = torch.unique(entries)  # [K] ascending
        else:
            listed = torch.zeros(len(self), dtype=torch.bool, device=self.device)  # [N]
            listed[entries] = True
            g = torch.nonzero(listed).squeeze(-1)  # [K] ascending
        gb = self.boxes.index_select(0, g)  # [K, 6]
        return g[(gb[:, :3] <= hi).all(-1) & (gb[:, 3:] >= lo).all(-1)]
