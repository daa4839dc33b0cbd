"""The blurred step read from tables (core/normal.py): SciPy's functions to the stated error."""

import numpy as np
import pytest
from scipy.special import erf, ndtr

from marker_localizer.core.normal import MAX_ERROR, tabulated_cdf, tabulated_erf

TABULATED = [
    pytest.param(tabulated_cdf, ndtr, id="cdf"),
    pytest.param(tabulated_erf, erf, id="erf"),
]


@pytest.mark.parametrize(("tabulated", "exact"), TABULATED)
def test_the_table_gives_scipys_function_to_the_stated_error_everywhere(tabulated, exact):
    # A grid finer than the table's, and far beyond its range on either side.
    x = np.linspace(-12.0, 12.0, 1_200_001)
    np.testing.assert_allclose(tabulated(x), exact(x), rtol=0, atol=MAX_ERROR)


@pytest.mark.parametrize(("tabulated", "exact"), TABULATED)
def test_float32_stays_float32_within_its_own_rounding(tabulated, exact):
    x = np.random.default_rng(0).normal(0.0, 3.0, 100_000).astype(np.float32)
    values = tabulated(x)
    assert values.dtype == np.float32
    np.testing.assert_allclose(values, exact(x.astype(np.float64)), rtol=0, atol=2 * MAX_ERROR)


@pytest.mark.parametrize("tabulated", [tabulated_cdf, tabulated_erf], ids=["cdf", "erf"])
def test_the_blurred_step_never_falls(tabulated):
    values = tabulated(np.linspace(-9.0, 9.0, 300_001))
    assert np.all(np.diff(values) >= 0.0)


@pytest.mark.parametrize(("tabulated", "exact"), TABULATED)
def test_nan_stays_nan_and_the_infinities_saturate(tabulated, exact):
    values = tabulated(np.array([np.nan, -np.inf, np.inf]))
    assert np.isnan(values[0])
    np.testing.assert_allclose(values[1:], exact(np.array([-np.inf, np.inf])), atol=MAX_ERROR)


@pytest.mark.parametrize("shape", [(), (0,), (3, 0), (2, 3, 4)])
def test_any_shape_comes_back_as_it_went_in(shape):
    x = np.zeros(shape)
    assert tabulated_cdf(x).shape == shape
    assert tabulated_erf(x).shape == shape


def test_integers_are_read_as_float64():
    values = tabulated_cdf(np.arange(-3, 4))
    assert values.dtype == np.float64
    np.testing.assert_allclose(values, ndtr(np.arange(-3, 4)), rtol=0, atol=MAX_ERROR)
