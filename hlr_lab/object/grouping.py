"""Rows of integer keys grouped, fast on millions: the merge of a scan's vertices into samples
(``object/clusters.py``) and the binning of its colours (``object/segment.py``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def group_rows(keys: np.ndarray | Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``keys`` (N, K) integer, or its K columns (N,) each of any integer type (a scan's, narrow,
    at a fraction of the memory), grouped: each row's group (N,) and its group's first row (G,), the groups
    in the rows' lexicographic order (as ``np.unique(keys, axis=0)`` orders them) when the rows fit one
    int64 in mixed radix — sorting integers is ~4× faster than sorting K-word byte strings — and in the
    bytes' order otherwise. The groups are int32 when fewer than 2³¹."""
    columns = list(keys.T) if isinstance(keys, np.ndarray) else [np.asarray(c) for c in keys]
    low = np.array([c.min(initial=0) for c in columns], dtype=np.int64)
    span = np.array([c.max(initial=0) for c in columns], dtype=np.int64) - low + 1  # (K,)
    if float(np.prod(span.astype(np.float64))) >= 2.0**62:
        wide = np.ascontiguousarray(np.column_stack(columns), dtype=np.int64)
        rows = wide.view(np.dtype((np.void, wide.dtype.itemsize * wide.shape[1]))).ravel()
        _, first, group = np.unique(rows, return_index=True, return_inverse=True)
        return group.ravel(), first
    radix = np.concatenate([np.cumprod(span[::-1])[::-1][1:], [1]])  # the last column varies fastest
    rows = np.zeros(len(columns[0]) if columns else 0, dtype=np.int64)
    for c, lo, r in zip(columns, low, radix, strict=True):  # a column at a time: no (N, K) int64 temporary
        rows += (c.astype(np.int64) - lo) * r
    # np.unique(rows, return_index=True, return_inverse=True), without its int64 inverse and second copy
    order = np.argsort(rows, kind="stable")  # stable: a group's first row in the sort is its first row
    rows = rows[order]
    starts = np.empty(len(rows), dtype=bool)
    starts[:1] = True
    np.not_equal(rows[1:], rows[:-1], out=starts[1:])
    del rows
    first = order[starts]
    index = np.int32 if len(first) < 2**31 else np.int64
    group = np.empty(len(order), dtype=index)
    group[order] = np.cumsum(starts, dtype=index) - 1
    return group, first
