"""The 'x y z' text of a point, as cinesplat-plan, both viewers and the scene loader read it: three numbers in any of
the usual spellings, exactly the numbers typed; anything else names an object."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from cinenerf_ns.point_text import parse_point

SEPARATORS = [" ", ", ", ",", "; ", "  \t"]


@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=3, max_size=3),
       st.sampled_from(SEPARATORS), st.sampled_from([("", ""), ("[", "]"), ("(", ")"), ("  ", " ")]))
def test_three_numbers_come_back_exactly(xyz, sep, brackets):
    text = brackets[0] + sep.join(repr(v) for v in xyz) + brackets[1]
    p = parse_point(text)
    assert p is not None and p.dtype == np.float64 and p.tolist() == xyz, text


@pytest.mark.parametrize("text,expected", [
    ("1 2 3", [1, 2, 3]),
    ("[0.1, -2e-1, 3.]", [0.1, -0.2, 3.0]),
    ("(1.5, -2e-1, .3)", [1.5, -0.2, 0.3]),
    ("  1;2;3 ", [1, 2, 3]),
])
def test_spellings(text, expected):
    assert parse_point(text).tolist() == expected


@pytest.mark.parametrize("text", ["nan 1 2", "[1, inf, 2]", "1e400 0 0"])
def test_non_finite_numbers_are_kept_for_the_caller_to_refuse(text):
    """The caller says which option or box holds them ('the go-to point ... is not finite'), not 'no object matches'."""
    p = parse_point(text)
    assert p is not None and not all(math.isfinite(v) for v in p)


@pytest.mark.parametrize("text", ["the red chair", "1 2", "1 2 3 4", "chair 1 2 3", "", "   ", "1 2 x", "lamp 2"])
def test_anything_else_names_an_object(text):
    assert parse_point(text) is None
