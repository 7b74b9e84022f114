"""The tracker's own linear sum assignment against SciPy's (the reference it reproduces)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment as scipy_lsap

from wfviz.tracking.lsap import linear_sum_assignment


@pytest.mark.parametrize("kind", ["random", "ties", "gated", "gated ties"])
def test_same_pairs_as_scipy(kind: str) -> None:
    """Wide, tall and square matrices, with many equal costs and with the tracker's large cost of
    an inadmissible pair: the same rows and columns as SciPy, ties broken the same way."""
    rng = np.random.default_rng(len(kind))
    for _ in range(1500):
        nr, nc = rng.integers(1, 9, 2)
        if "ties" in kind:
            cost = rng.integers(0, 3, (nr, nc)) * 0.25
        else:
            cost = rng.random((nr, nc))
        if "gated" in kind:
            cost[rng.random((nr, nc)) < 0.5] = 1e9
        rows, cols = linear_sum_assignment(cost)
        want_rows, want_cols = scipy_lsap(cost)
        assert rows.tolist() == want_rows.tolist() and cols.tolist() == want_cols.tolist(), cost


def test_edge_cases_and_errors() -> None:
    assert [a.tolist() for a in linear_sum_assignment(np.zeros((0, 3)))] == [[], []]
    assert [a.tolist() for a in linear_sum_assignment(np.ones((3, 3)))] == [[0, 1, 2], [0, 1, 2]]
    inf = np.inf
    rows, cols = linear_sum_assignment(np.array([[inf, 1.0], [2.0, inf]]))
    assert rows.tolist() == [0, 1] and cols.tolist() == [1, 0]
    with pytest.raises(ValueError, match="infeasible"):
        linear_sum_assignment(np.array([[inf, 1.0], [inf, 2.0]]))
    with pytest.raises(ValueError, match="invalid"):
        linear_sum_assignment(np.array([[np.nan, 1.0]]))
    with pytest.raises(ValueError, match="2-D"):
        linear_sum_assignment(np.zeros(3))
