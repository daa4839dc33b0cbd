"""refinement="template": the one decision, its reasons and its calibrated threshold."""

import numpy as np
import pytest

from marker_localizer.core import decision


def _marker_like(**changes: float) -> decision.Evidence:
    """One candidate's evidence that passes every hard test, with ``changes`` applied."""
    values = {
        "converged": True,
        "line_angle_rad": np.pi / 2,
        "edge_t": 40.0,
        "extent_px": 12.0,
        "extent_balance": 0.95,
        "fit_ratio": 1.0,
        "contrast": 120.0,
        "blur_px": 1.0,
        "light_change": 0.05,
        "step_ratio": 0.9,
        "shadow_depth": 0.0,
        "point_symmetry": 0.95,
    } | changes
    return decision.Evidence(**{name: np.array([value]) for name, value in values.items()})


def _decide(evidence: decision.Evidence, threshold: float = -1e9) -> str:
    verdict = decision.decide(
        evidence, min_radius_px=6.0, min_extent_fraction=0.7, threshold=threshold
    )
    reason = int(verdict.reason[0])
    assert verdict.accepted[0] == (reason < 0)
    return "accepted" if reason < 0 else decision.REASONS[reason]


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({}, "accepted"),
        ({"converged": False}, "fit"),
        ({"line_angle_rad": np.deg2rad(10.0)}, "fit"),
        ({"edge_t": -5.0}, "sector_order"),  # the quadrants do not alternate
        ({"step_ratio": 0.05}, "sector_order"),
        ({"extent_px": 3.0}, "extent"),  # under 0.7 of the smallest radius, 6 px
        ({"extent_balance": 0.5}, "extent"),
        ({"blur_px": 3.0}, "optics"),
        ({"light_change": 0.8}, "optics"),
        # Of several failing tests, the first in REASONS' order is the reason.
        ({"converged": False, "blur_px": 3.0, "extent_px": 3.0}, "fit"),
        ({"extent_px": 3.0, "light_change": 0.8}, "extent"),
    ],
)
def test_a_candidate_is_rejected_for_the_first_test_it_fails(changes, reason):
    assert _decide(_marker_like(**changes)) == reason


def test_a_candidate_that_passes_every_hard_test_is_decided_by_its_score():
    evidence = _marker_like()
    score = float(decision.marker_score(evidence, 6.0)[0])
    assert _decide(evidence, threshold=score - 1e-9) == "accepted"
    assert _decide(evidence, threshold=score + 1e-9) == "score"


def test_weaker_evidence_scores_lower():
    strong = decision.marker_score(_marker_like(), 6.0)[0]
    for changes in ({"edge_t": 8.0}, {"fit_ratio": 3.0}, {"point_symmetry": 0.3}):
        assert decision.marker_score(_marker_like(**changes), 6.0)[0] < strong, changes


def test_the_threshold_rises_by_the_tails_scale_for_each_factor_e_fewer_false_points():
    start, rate, scale = decision.FALSE_ALARM_TAIL
    assert decision.threshold_for_rate(rate) == pytest.approx(start)
    stricter = decision.threshold_for_rate(rate / np.e)
    assert stricter - decision.threshold_for_rate(rate) == pytest.approx(scale)
    assert decision.threshold_for_rate(0.01) > decision.threshold_for_rate(0.1)


def test_confidence_is_one_half_at_even_odds_and_saturates_without_overflow():
    confidence = decision.confidence(np.array([-1e4, -1.0, 0.0, 1.0, 1e4]))
    assert confidence[2] == 0.5
    assert np.all(np.diff(confidence) > 0)
    assert 0.0 < confidence[0] < 1e-20 and 1.0 - confidence[-1] < 1e-20


def test_the_evidence_names_every_feature_the_score_weighs():
    features = decision.score_features(_marker_like(), 6.0)
    assert features.shape == (1, len(decision.SCORE_FEATURES)) == (1, len(decision.SCORE_WEIGHTS))
