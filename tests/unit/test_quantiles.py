"""Percentiles in constant memory (``swarm.runs.quantiles``) against the exact ones."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.errors import InputError
from swarm.runs.quantiles import Quantiles

pytestmark = pytest.mark.unit


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(1e-6, 10.0, allow_nan=False), min_size=1, max_size=400),
    st.sampled_from([0.0, 1.0, 50.0, 90.0, 99.0, 100.0]),
)
def test_a_percentile_is_the_exact_ranks_within_half_a_bin(xs, q):
    h = Quantiles()
    for x in xs:
        h.add(x)
    exact = float(np.percentile(xs, q, method="inverted_cdf"))
    got = h.percentile(q)
    assert got is not None
    assert exact / 10 ** (0.5 / h.per_decade) * (1 - 1e-12) <= got <= exact * 10 ** (0.5 / h.per_decade) * (1 + 1e-12)
    assert h.count == len(xs) and h.min == min(xs) and h.max == max(xs)


def test_memory_is_constant_and_merging_is_adding():
    rng = np.random.default_rng(0)
    a, b, both = Quantiles(), Quantiles(), Quantiles()
    xs = rng.lognormal(-6, 1, 200_000)
    for i, x in enumerate(xs.tolist()):
        (a if i % 2 else b).add(x)
        both.add(x)
    size = a._counts.nbytes
    a.merge(b)
    assert a._counts.nbytes == size and a.count == both.count
    assert a.percentile(99) == both.percentile(99) and a.percentile(50) == both.percentile(50)
    assert a.percentile(50) == pytest.approx(float(np.median(xs)), rel=0.012)


def test_edges_empty_zero_and_bad_values():
    h = Quantiles()
    assert h.percentile(50) is None
    h.add(0.0)  # (below the lowest bin: counted there, reported as the exact smallest)
    assert h.percentile(50) == 0.0
    with pytest.raises(InputError):
        h.add(float("nan"))
    with pytest.raises(InputError):
        h.percentile(101)
    with pytest.raises(InputError):
        Quantiles(lo=1.0, hi=0.5)
    with pytest.raises(InputError):
        h.merge(Quantiles(per_decade=10))
