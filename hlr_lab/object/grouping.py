"""Rows of integer keys grouped, fast on millions: the merge of a scan's vertices into samples
(``object/clusters.py``) and the binning of its colours (``object/segment.py``); and a graph's nodes
grouped by what joins them (segment's same-colour patches)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

_EDGE_BLOCK = 1 << 20  # edges converted to the narrow index a block at a time


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


def connected_groups(n: int, u: np.ndarray, v: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """(n,) the connected component of each of n nodes joined by the edges u[i]–v[i] ((E,) each, any
    integer type; only those ``where`` (E,) bool is True, if given), numbered by their lowest node (as
    ``scipy.sparse.csgraph.connected_components`` numbers them); int32 when n < 2³¹.

    Union by hooking each root on the smallest root an edge joins it to, then compressing every node's
    pointer to its root, until no edge joins two roots (a few rounds on a mesh). In ~13 bytes an edge
    (int32) at most, where scipy's graph is a float64 CSR and its transpose, after int64 copies of the edges."""
    index = np.int32 if n < 2**31 else np.int64
    keep = np.ones(len(u), bool) if where is None else where
    low = np.empty(int(np.count_nonzero(keep)), index)
    high = np.empty_like(low)
    at = 0
    for start in range(0, len(u), _EDGE_BLOCK):  # no int64 copy of all the edges at once
        block = slice(start, start + _EDGE_BLOCK)
        a, b = u[block][keep[block]], v[block][keep[block]]
        low[at : at + len(a)], high[at : at + len(a)] = np.minimum(a, b), np.maximum(a, b)
        at += len(a)
    root = np.arange(n, dtype=index)
    while len(low):
        np.minimum.at(root, high, low)  # roots only point down: no cycles
        while True:
            hop = root[root]
            if np.array_equal(hop, root):
                break
            root = hop
        low = root[low]  # each edge's two roots; rebound one at a time: three edge arrays alive at most
        high = root[high]
        apart = low != high
        low = low[apart]
        high = high[apart]
        del apart
        smaller = np.minimum(low, high)
        np.maximum(low, high, out=high)
        low = smaller

    is_root = root == np.arange(n, dtype=index)
    return (np.cumsum(is_root, dtype=index) - 1)[root]
