"""Specification of the bound's Monte Carlo check (marker_localizer.bench.efficiency)."""

from __future__ import annotations

import pytest

from marker_localizer.bench import efficiency


def test_the_xs_bound_is_the_renderers_and_the_whole_window_holds_more_information():
    # The renderer's bound, like truth.json's, sums the X's pixels alone: the arcs and
    # the plate's outline against the ground lower the whole window's to about 0.75.
    check = efficiency.check_efficiency(8.0, 30.0, 0.8, 3.0, draws=0)
    assert check.window_bound_px < 0.85 * check.bound_px


def test_a_maximum_likelihood_fit_of_the_whole_window_goes_under_the_xs_bound():
    # Everything but the centre known, as in the bound's model: over the X's pixels
    # the fit is about efficient (1.11 of the bound on these 24 frames, 1.01-1.05 on
    # 400), over the whole window it reaches 0.71 of it (0.71-0.82 on 400), so the
    # bound is no floor for every unbiased estimator.
    check = efficiency.check_efficiency(8.0, 30.0, 0.8, 3.0, draws=24)
    assert check.x_mean_error_px == pytest.approx(check.bound_px, rel=0.2)
    assert check.window_mean_error_px < 0.9 * check.bound_px
