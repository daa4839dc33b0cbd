"""The standard normal's distribution function and erf, read from tables.

Every edge the marker models draw is a step blurred by a Gaussian: the plate's
square, the quarter disks' arc, the X's two lines, a cast shadow's edge. SciPy's
``ndtr`` and ``erf`` evaluate it to double precision at about 13 ns a value, a
tenth of a 12 MP frame's detection on the models' grids of shapes and blurs. A
table of the function every :data:`STEPS_PER_UNIT`-th of a unit, read by linear
interpolation, gives it to within :data:`MAX_ERROR` in 55-70 % of that time,
far under the noise the models are compared with (a thousandth of the contrast
and more) and under float32's own rounding of values near 1.

A table's function is piecewise linear: its slope is off the density by up to
a four-hundredth, so the fits that step along the analytic derivative of the
model they evaluate (the template path's, :mod:`~marker_localizer.core.uneven`'s,
:mod:`~marker_localizer.core.shadow`'s) keep SciPy's. The tables serve where a
step is evaluated and not differentiated: the plate's search over its shapes, the
blurred X of the template's correlation and the line fit's levels.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf as _exact_erf
from scipy.special import ndtr as _exact_ndtr

#: The tables' half range: beyond it the distribution function is 0 or 1 to
#: within 7e-16 (Phi(-8)), erf -1 or 1 to within 2e-29 (erfc(8)).
LIMIT = 8.0
#: Table entries a unit of the argument: linear interpolation errs by at most h^2 / 8
#: times the function's largest curvature (0.242 for Phi, 0.968 for erf), h the
#: spacing.
STEPS_PER_UNIT = 512
#: The most either function read from its table differs from SciPy's, float64 input.
MAX_ERROR = 5e-7

_GRID = np.linspace(-LIMIT, LIMIT, int(2 * LIMIT * STEPS_PER_UNIT) + 1)


def _table(values: NDArray[np.float64]) -> dict[type, tuple[NDArray[Any], NDArray[Any]]]:
    """Each entry and its step to the next, in float64 and float32."""
    steps = np.diff(values, append=values[-1])
    return {
        dtype: (values.astype(dtype), steps.astype(dtype)) for dtype in (np.float64, np.float32)
    }


_CDF = _table(_exact_ndtr(_GRID))
_ERF = _table(_exact_erf(_GRID))


def _read(tables: dict[type, tuple[NDArray[Any], NDArray[Any]]], x: NDArray[Any]) -> NDArray[Any]:
    """``tables`` interpolated at ``x``: float32 for float32 input, else float64; NaN stays NaN."""
    x = np.asarray(x)
    dtype = np.float32 if x.dtype == np.float32 else np.float64
    values, steps = tables[dtype]
    # At least 1-d: the in-place steps need arrays, which a 0-d input's casts are not.
    # Clamped by the method: np.clip's wrapper costs microseconds a call on small reads.
    position: NDArray[np.floating[Any]] = (
        np.atleast_1d(x).clip(-LIMIT, LIMIT).astype(dtype, copy=False)
    )
    position += LIMIT
    position *= STEPS_PER_UNIT
    # The whole steps in the positions' own dtype (they are >= 0: the floor is the cast's
    # truncation), so the fraction is taken without integers cast to float64 and back.
    whole: NDArray[np.floating[Any]] = np.floor(position)
    # A NaN's index is whatever the cast makes of it, clipped into the table by the
    # reads: its fraction stays NaN, and so does the value.
    with np.errstate(invalid="ignore"):
        index = whole.astype(np.intp)
    position -= whole
    # Three arrays a call, the fraction's taking the entries in turn: a frame's arrays
    # of 10^5 values and more come fresh from the kernel, page by page.
    result = steps.take(index, mode="clip")
    result *= position
    result += values.take(index, mode="clip", out=position)
    return result.reshape(x.shape)


def tabulated_cdf(x: NDArray[Any]) -> NDArray[Any]:
    """The standard normal's distribution function Phi (SciPy's ``ndtr``) to :data:`MAX_ERROR`.

    Args:
        x: any shape; float32 in, float32 out, anything else float64.
    """
    return _read(_CDF, x)


def tabulated_erf(x: NDArray[Any]) -> NDArray[Any]:
    """The error function, 2 Phi(x sqrt 2) - 1 (SciPy's ``erf``), to :data:`MAX_ERROR`.

    Args:
        x: any shape; float32 in, float32 out, anything else float64.
    """
    return _read(_ERF, x)
