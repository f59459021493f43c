"""The estimator's median and percentile are NumPy's, value for value, and do not import numpy.ma."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

from spherecal.estimation.robust import median, percentile


@pytest.mark.parametrize("shape,axis", [((1,), None), ((2,), None), ((7,), None), ((10,), None), ((5, 4), 0),
                                        ((5, 4), 1), ((4, 6), -1), ((3, 1, 5), 2), ((3, 8, 5), 1), ((6, 3), None)])
def test_median_equals_numpys_bit_for_bit(shape, axis):
    rng = np.random.default_rng(sum(shape))
    for a in (rng.normal(size=shape) * 1e3, rng.integers(0, 4, size=shape).astype(float)):  # ties too
        got, want = median(a, axis=axis), np.median(a, axis=axis)
        assert np.shape(got) == np.shape(want)
        assert np.array_equal(got, want)
        assert isinstance(got, np.floating) == isinstance(want, np.floating)


def test_median_of_a_list_and_nan_as_numpy():
    assert median([3.0, 1.0, 2.0, 10.0]) == 2.5
    a = np.array([[1.0, np.nan, 3.0], [4.0, 5.0, 6.0]])
    assert np.array_equal(median(a, axis=1), np.median(a, axis=1), equal_nan=True)
    assert np.isnan(median([1.0, np.nan]))


def test_median_of_nothing_is_nan():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert np.array_equal(median(np.empty((0, 3)), axis=0), np.median(np.empty((0, 3)), axis=0), equal_nan=True)
    assert np.isnan(median([]))


def test_median_does_not_import_numpy_ma():
    code = ("import sys, numpy as np; from spherecal.estimation.robust import median, percentile; "
            "median(np.arange(5.0)); median(np.ones((3, 4)), axis=1); percentile(np.arange(7.0), 95); print('numpy.ma' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 19, 20, 21, 100, 1001])
def test_percentile_equals_numpys_bit_for_bit(n):
    rng = np.random.default_rng(n)
    for a in (rng.normal(size=n), np.abs(rng.standard_cauchy(size=n)), rng.integers(0, 3, size=n).astype(float)):
        for q in (0, 1, 5, 33.3, 50, 90, 95, 99, 100):
            got, want = percentile(a, q), np.percentile(a, q)
            assert got == want and type(got) is type(want), (q, got, want)
    assert np.isnan(percentile(np.array([1.0, np.nan, 2.0]), 95)) and np.isnan(percentile([], 95))
