"""A box the user gives (--region, the viewers' region fold, a stored region): six finite numbers with lo < hi on every
axis come back as two corners, exactly; anything else is refused with a message naming where the box came from."""
import numpy as np
import pytest
from hypothesis import assume, given, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.user_box import format_point, user_box

finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(st.lists(finite, min_size=3, max_size=3), st.lists(st.floats(1e-6, 1e6), min_size=3, max_size=3),
       st.booleans())
def test_a_valid_box_comes_back_exactly(lo, size, as_six):
    hi = [a + b for a, b in zip(lo, size)]
    assume(all(h > a for a, h in zip(lo, hi)))  # not a side under the rounding of lo
    got = user_box(lo + hi if as_six else (lo, hi))
    assert got[0].dtype == np.float64 and got[0].tolist() == lo and got[1].tolist() == hi


@pytest.mark.parametrize("bounds,regex", [
    ((np.zeros(3), np.zeros(3)), r"empty or inverted along x, y, z"),
    (([0, 0, 0], [1, -1, 1]), r"empty or inverted along y"),
    (([0, 0, np.nan], [1, 1, 1]), r"must be 6 finite numbers"),
    (([0, 0, 0], [1, 1, np.inf]), r"must be 6 finite numbers"),
    (([0, 0], [1, 1]), r"must be 6 numbers .* got 4 numbers"),
    (("a", "b"), r"must be 6 numbers"),
])
def test_bad_boxes_are_clear_errors(bounds, regex):
    with pytest.raises(InvalidInputError, match=regex):
        user_box(bounds, "the planning region (--region)")


def test_the_message_names_the_box_and_its_corners():
    with pytest.raises(InvalidInputError, match=r"the stored planning region is empty or inverted along z: .*"
                                                r"got \(0, 0, 1\)\.\.\(1, 1, 0\.5\)"):
        user_box(([0, 0, 1], [1, 1, 0.5]), "the stored planning region")
    assert format_point(np.array([1.23456, -1e-5, 2e6])) == "(1.23, -1e-05, 2e+06)"
