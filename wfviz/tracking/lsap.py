"""Linear sum assignment for the tracker's small gated problems, without SciPy.

The shortest augmenting path algorithm of Crouse (2016, "On implementing 2D rectangular
assignment algorithms", IEEE TAES 52(4), pp. 1685-1686), step for step as SciPy's
``scipy.optimize.linear_sum_assignment`` runs it (its tie-breaking and the transposition of tall
matrices included), so both return the same pairs: ``tests/test_lsap.py`` checks it against
SciPy. Plain Python: meant for the tens of rows and columns a frame's gates give (about 20 µs
for 6 x 9, 0.6 ms for 30 x 60), where importing SciPy's solver would cost about 0.45 s of start-up.
The scoring modules, whose matrices can be large, keep SciPy's compiled one.
"""

from __future__ import annotations

import numpy as np


def linear_sum_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the pairs minimising the summed ``cost`` (2-D, finite or +inf): every row
    paired when there are fewer rows than columns, else every column; rows in increasing order.
    Raises ValueError for NaN or -inf entries, or when +inf leaves no complete assignment."""
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"expected a matrix (2-D array), got a {c.ndim}-D array")
    nr, nc = c.shape
    if nr == 0 or nc == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    transpose = nc < nr
    if transpose:
        c = np.ascontiguousarray(c.T)
        nr, nc = nc, nr
    if np.isnan(c).any() or (c == -np.inf).any():
        raise ValueError("matrix contains invalid numeric entries")
    col4row = _solve(c)
    if transpose:
        order = np.argsort(col4row, kind="stable")
        return col4row[order], order.astype(np.int64)
    return np.arange(nr, dtype=np.int64), col4row


def _solve(cost: np.ndarray) -> np.ndarray:
    """Column of each row of a wide (rows <= columns) cost matrix. Plain Python floats: for the
    few rows and columns of a gated problem they are faster than NumPy's per-call overhead."""
    nr, nc = cost.shape
    rows: list[list[float]] = cost.tolist()
    inf = float("inf")
    u = [0.0] * nr
    v = [0.0] * nc
    path = [-1] * nc
    col4row = [-1] * nr
    row4col = [-1] * nc
    for cur in range(nr):
        # the shortest augmenting path from row cur
        remaining = list(range(nc - 1, -1, -1))  # reversed: a constant matrix gives the identity
        spc = [inf] * nc
        sr = [False] * nr
        sc = [False] * nc
        min_val = 0.0
        i = cur
        sink = -1
        while sink == -1:
            index = -1
            lowest = inf
            sr[i] = True
            row, ui = rows[i], u[i]
            for it, j in enumerate(remaining):
                r = min_val + row[j] - ui - v[j]
                if r < spc[j]:
                    path[j] = i
                    spc[j] = r
                # among equal minima, one that ends the path (an unassigned column)
                if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                    lowest = spc[j]
                    index = it
            min_val = lowest
            if min_val == inf:
                raise ValueError("cost matrix is infeasible")
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            sc[j] = True
            remaining[index] = remaining[-1]
            remaining.pop()
        # update the dual variables
        u[cur] += min_val
        for i in range(nr):
            if sr[i] and i != cur:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if sc[j]:
                v[j] -= min_val - spc[j]
        # augment the previous solution along the path
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == cur:
                break
    return np.asarray(col4row, dtype=np.int64)
