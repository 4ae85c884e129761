"""The property tests' profiles (tests/conftest.py): `make test` runs every hypothesis test derandomised with no example
database (the same examples on every run and machine); `make fuzz` (--hypothesis-profile=fuzz) draws random examples,
FUZZ_FACTOR times each test's own max_examples."""
from __future__ import annotations

import pytest
from hypothesis import given, settings, strategies as st


@settings(max_examples=3, deadline=None)
@given(x=st.integers(0, 10))
def test_a_property_test_of_this_profile(x):
    assert 0 <= x <= 10


@pytest.mark.hypothesis  # selected by `make fuzz` (-m hypothesis) too
def test_property_tests_are_derandomised_in_make_test_and_random_in_make_fuzz(fuzz_factor):
    s = test_a_property_test_of_this_profile._hypothesis_internal_use_settings
    profile = settings.get_current_profile_name()
    assert profile in ("ci", "fuzz"), f"profile {profile!r}: tests/conftest.py loads 'ci' unless fuzzing"
    assert s.deadline is None  # nothing timed: a loaded machine fails no test
    if profile == "ci":
        assert s.derandomize and s.database is None and s.max_examples == 3
    else:
        assert not s.derandomize and s.max_examples == 3 * fuzz_factor
