"""The scene and index arguments every compiled polytope.c entry point starts with: which scenes the kernels apply to
(``native_applies``) and the contiguous arrays and pointer tables they read (``native_arrays``, built once per scene
and index pair, kept on the index).

Its users: geometry's point test, capped distance and sight-line test (collision.py, distance.py, occlusion.py),
corridor's safe polytope (corridor/polytope_native.py), search/reach.py and shots/refine.py.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .ranges import group_ranks


def native_applies(scene, index) -> bool:
    """The compiled polytope and point test can run on this scene and index: a CPU scene (float32 or float64) and a
    GridIndex on the CPU."""
    return (index is not None and hasattr(index, "levels") and scene.means.device.type == "cpu"
            and index.device.type == "cpu" and scene.means.dtype in (torch.float32, torch.float64))


def _round_f32(x: np.ndarray, down: bool) -> np.ndarray:
    """float64 x as float32, rounded toward -inf (down) or +inf (so the float32 value bounds x)."""
    y = x.astype(np.float32)
    if down:
        return np.where(y.astype(np.float64) > x, np.nextafter(y, np.float32(-np.inf)), y)
    return np.where(y.astype(np.float64) < x, np.nextafter(y, np.float32(np.inf)), y)


def _positions_by_cell(level, inv: np.ndarray) -> tuple[Tensor, Tensor]:
    """A GridIndex level's ids [M] as native positions (``inv`` [N]: scene id -> position), ascending within each cell
    (same cells, same offsets): a cell's rows are then read in memory order (about 2.5x faster polytopes at 1M
    Gaussians than positions left in scene-id order); and each entry's home bits [M] uint8 (polytope.c's header):
    bit i set when the entry's cell is the first along axis i of the cells the level lists its ellipsoid in."""
    pos = inv[level.ids.long().cpu().numpy()]  # [M]
    off = level.offsets.long().cpu().numpy()
    cell, _ = group_ranks(np.diff(off))  # [M] each entry's cell, ascending (CSR)
    n = max(len(inv), 1)
    pos = np.sort(cell * n + pos) - cell * n  # one sort of (cell, position) keys: cells stay in place
    dy, dz = (int(v) for v in level.dims[1:].tolist())
    # the entries' cell coordinates in int32 (a level has at most GridIndex's max_cells cells): int64 division of
    # ~12M entries at 1M Gaussians took 0.4 s of prepare
    q, cz = np.divmod(cell.astype(np.int32), np.int32(dz))
    cx, cy = np.divmod(q, np.int32(dy))
    homes = np.zeros(len(pos), dtype=np.uint8)
    for i, c in enumerate((cx, cy, cz)):
        first = np.full(n, np.iinfo(np.int32).max, dtype=np.int32)
        np.minimum.at(first, pos, c)  # per ellipsoid, its first cell along axis i
        homes |= (c == first[pos]).view(np.uint8) << np.uint8(i)
    return torch.from_numpy(pos), torch.from_numpy(homes)


def native_arrays(scene, index) -> dict:
    """Contiguous CPU arrays and ctypes pointer tables the compiled polytope reads (built once per scene/index pair,
    kept on the index so the memory they point into stays alive). "args": the scene and index arguments every
    compiled call starts with; "perm": native position -> scene id."""
    import ctypes

    cache = getattr(index, "_native_polytope_arrays", None)
    if cache is not None and cache["scene"] is scene:
        return cache
    from ..scene.spatial_index import morton_order

    dt = scene.means.dtype
    # The compiled code reads the ellipsoids in spatial (Morton) order: its ids are positions in that order, and
    # "perm" maps them back to scene ids (native position -> scene id). A query visits one region, whose rows are
    # then close in memory; in the scene's own order neighbours are scattered over the whole array (Morton order
    # about halves the polytope time at 1M Gaussians).
    perm = morton_order(scene.means)  # [N]
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(perm), dtype=np.int64)
    perm_t = torch.from_numpy(perm)
    keep = {
        "perm": perm,
        "means": scene.means.detach()[perm_t].contiguous(),
        "rots": scene.rotations.detach().to(dt)[perm_t].contiguous(),
        "radii": scene.radii.detach().to(dt)[perm_t].contiguous(),
    }
    # one float32 row per ellipsoid for the gather (polytope.c's header): padded AABB lo rounded down, hi rounded
    # up, mean, largest semi-axis rounded up (rounding only widens the tests that read them)
    boxes = index.boxes.detach().double().cpu().numpy()[perm]  # [N, 6]
    pack = np.zeros((len(index), 12), dtype=np.float32)
    pack[:, :3] = _round_f32(boxes[:, :3], down=True)
    pack[:, 3:6] = _round_f32(boxes[:, 3:], down=False)
    pack[:, 6:9] = keep["means"].cpu().numpy()
    pack[:, 9] = _round_f32(keep["radii"].double().max(-1).values.cpu().numpy(), down=False)
    pack[:, 10] = _round_f32(keep["radii"].double().min(-1).values.cpu().numpy(), down=True)  # distance upper bounds
    keep["pack"] = pack
    keep["origin"] = index.origin.double().contiguous()
    keep["cells"] = np.array([lv.cell for lv in index.levels], dtype=np.float64)
    keep["dims"] = np.ascontiguousarray(np.stack([lv.dims.cpu().numpy() for lv in index.levels]).astype(np.int64))
    keep["offsets_t"] = [lv.offsets.long().contiguous() for lv in index.levels]
    keep["ids_t"], keep["homes_t"] = (list(v) for v in zip(*[_positions_by_cell(lv, inv) for lv in index.levels]))
    L = len(index.levels)
    keep["offsets"] = (ctypes.c_void_p * L)(*[t.data_ptr() for t in keep["offsets_t"]])
    keep["ids"] = (ctypes.c_void_p * L)(*[t.data_ptr() for t in keep["ids_t"]])
    keep["homes"] = (ctypes.c_void_p * L)(*[t.data_ptr() for t in keep["homes_t"]])
    keep["scene"] = scene
    # the scene and index arguments every compiled call starts with (see native/polytope.c)
    keep["args"] = (
        keep["means"].data_ptr(), keep["rots"].data_ptr(), keep["radii"].data_ptr(), pack.ctypes.data,
        int(dt == torch.float32), keep["origin"].data_ptr(), L, keep["cells"].ctypes.data, keep["dims"].ctypes.data,
        ctypes.cast(keep["offsets"], ctypes.c_void_p), ctypes.cast(keep["ids"], ctypes.c_void_p),
        ctypes.cast(keep["homes"], ctypes.c_void_p), float(index.pad),
    )
    index._native_polytope_arrays = keep
    return keep
