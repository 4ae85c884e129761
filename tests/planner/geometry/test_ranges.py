"""group_ranks (cinenerf_ns/planner/geometry/ranges.py) against a plain loop."""
import numpy as np
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.geometry.ranges import group_ranks


@settings(max_examples=100, deadline=None)
@given(counts=st.lists(st.integers(0, 6), max_size=12))
def test_group_ranks_is_the_loop(counts):
    owner, rank = group_ranks(np.asarray(counts, dtype=np.int64))
    want = [(k, r) for k, c in enumerate(counts) for r in range(c)]
    assert owner.tolist() == [k for k, _ in want] and rank.tolist() == [r for _, r in want]
