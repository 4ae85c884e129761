"""PrefetchedIndex answers query_box exactly like the GridIndex (same ids) for sub-boxes of prefetched
boxes and for unforeseen boxes (fallback); corridors built through it are identical."""
import numpy as np
import torch
from hypothesis import given, settings, strategies as st

from _shot_scenes import GO_TO, walled_target_scene
from cinenerf_ns.planner.corridor import build_corridor
from cinenerf_ns.planner.prefetch_index import PrefetchedIndex, corridor_prefetch
from cinenerf_ns.planner.scene import EllipsoidScene, quat_wxyz_to_rotmat
from cinenerf_ns.planner.spatial_index import GridIndex


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 300), dtype=st.sampled_from([torch.float32, torch.float64]))
def test_query_box_equals_grid_index(seed, n, dtype):
    rng = np.random.default_rng(seed)
    sc = EllipsoidScene(torch.as_tensor(rng.uniform(-1, 1, (n, 3))).to(dtype),
                        quat_wxyz_to_rotmat(torch.as_tensor(rng.normal(size=(n, 4)))).to(dtype),
                        torch.as_tensor(np.exp(rng.uniform(-5, -1.5, (n, 3)))).to(dtype),
                        torch.ones(n, dtype=dtype), camera_radius=0.03)
    idx = GridIndex.build(sc)
    c = rng.uniform(-1, 1, (6, 3))
    h = rng.uniform(0.01, 0.5, (6, 3))
    pre = PrefetchedIndex(idx, c - h, c + h)
    for b in range(6):
        # a random sub-box (computed in the scene dtype, as polytope._candidates does) and the box itself
        f0, f1 = np.sort(rng.uniform(0, 1, (2, 3)), axis=0)
        lo = torch.as_tensor(c[b] - h[b] + 2 * h[b] * f0).to(dtype)
        hi = torch.as_tensor(c[b] - h[b] + 2 * h[b] * f1).to(dtype)
        for qlo, qhi in ((lo, hi), (torch.as_tensor(c[b] - h[b]).to(dtype), torch.as_tensor(c[b] + h[b]).to(dtype))):
            assert torch.equal(pre.query_box(qlo, qhi), idx.query_box(qlo, qhi))
    assert pre.misses == 0
    far = torch.tensor([5.0, 5.0, 5.0], dtype=dtype)
    assert torch.equal(pre.query_box(-far, far), idx.query_box(-far, far))  # unforeseen: fallback
    assert pre.misses == 1


def test_corridor_through_prefetch_is_identical():
    sc = walled_target_scene()
    idx = GridIndex.build(sc)
    ways = [np.array([[0.7, 0.6, 0.5], [0.6, 0.0, 0.8], GO_TO]), np.array([[-0.6, -0.9, 0.4], [0.1, -0.92, 0.5], GO_TO])]
    pre = corridor_prefetch(idx, ways, 0.15, sc.camera_radius)
    for w in ways:
        a = build_corridor(torch.as_tensor(w), sc, idx, box_margin=0.15)
        b = build_corridor(torch.as_tensor(w), sc, pre, box_margin=0.15)
        assert len(a) == len(b)
        for pa, pb in zip(a.polytopes, b.polytopes):
            assert torch.equal(pa.A, pb.A) and torch.equal(pa.b, pb.b)
    assert pre.misses == 0 and pre.hits > 0
