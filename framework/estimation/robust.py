"""Order statistics for the estimator.

:func:`median` gives exactly what ``np.median`` gives (the same middle elements, the
mean of the middle two of an even count, NaN where a NaN is among the values) without
``np.median``'s NaN check, which imports ``numpy.ma`` on its first call: about 10-25 ms
of a small ``solve``, whose start-up tests/cli/test_startup_imports.py bounds.
"""

from __future__ import annotations

import numpy as np


def median(values, axis: int | None = None):
    """``np.median(values, axis=axis)``, value for value: a NumPy float for
    ``axis=None``, else an array with ``axis`` removed. No values along ``axis`` give
    NaN (NumPy also warns)."""
    a = np.asarray(values, dtype=float)
    if axis is None:
        a, axis = a.ravel(), 0
    axis = axis % a.ndim
    n = a.shape[axis]
    if n == 0:
        out = np.full(np.delete(a.shape, axis), np.nan)
        return np.float64(np.nan) if out.ndim == 0 else out
    lo, hi = (n - 1) // 2, n // 2
    part = np.partition(a, sorted({lo, hi}), axis=axis)
    low, high = np.take(part, lo, axis=axis), np.take(part, hi, axis=axis)
    mid = low if lo == hi else (low + high) / 2
    has_nan = np.isnan(a).any(axis=axis)
    if np.ndim(mid) == 0:
        return np.float64(np.nan) if has_nan else np.float64(mid)
    return np.where(has_nan, np.nan, mid)


def percentile(values, q: float) -> np.float64:
    """``np.percentile(values, q)`` (linear interpolation), value for value, for the
    values of a 1-D array; ``np.percentile`` imports ``numpy.ma`` on its first call too."""
    a = np.asarray(values, dtype=float).ravel()
    n = len(a)
    if n == 0:
        return np.float64(np.nan)
    virtual = (n - 1) * (np.float64(q) / 100)
    if virtual >= n - 1:
        lo = hi = n - 1
    elif virtual < 0:
        lo = hi = 0
    else:
        lo = int(np.floor(virtual))
        hi = lo + 1
    gamma = float(virtual - lo)
    part = np.partition(a, sorted({lo, hi}))
    if np.isnan(a).any():
        return np.float64(np.nan)
    below, above = part[lo], part[hi]
    step = above - below
    # NumPy's interpolation: from below for gamma < 0.5, from above otherwise (exact at both ends)
    return np.float64(below + step * gamma) if gamma < 0.5 else np.float64(above - step * (1 - gamma))
