"""One frame as the detector's stages read it, and where they report."""

import numpy as np

from marker_localizer.core import frame as frame_module
from marker_localizer.core.frame import Frame, StageTimer
from marker_localizer.core.preprocessing import LocalGamma
from marker_localizer.core.result import DetectionResult


def test_a_stage_timed_twice_adds_both_times(monkeypatch):
    ticks = iter([1.0, 1.5, 10.0, 10.25])
    monkeypatch.setattr(frame_module.time, "perf_counter", lambda: next(ticks))
    timings: dict[str, float] = {}
    timer = StageTimer(timings)
    with timer("screening"):
        pass
    with timer("screening"):
        pass
    assert timings == {"screening": 750.0}


def _frame() -> Frame:
    gray = np.random.default_rng(3).integers(0, 255, (64, 64)).astype(np.uint8)
    gamma = LocalGamma(gray, 255.0, 0.5, 32)
    result = DetectionResult(counts={"candidates": 12, "accepted": 2})
    return Frame(gray, 255.0, gamma, result, StageTimer(result.timings_ms))


def test_a_second_reading_reports_to_fresh_counts_and_shares_the_frames_noise():
    first = _frame()
    noise = first.noise()
    again = first.reread()
    assert again.result is not first.result
    assert again.result.counts == {"candidates": 0, "accepted": 0}
    assert first.result.counts == {"candidates": 12, "accepted": 2}
    assert again.slope_centred and not first.slope_centred
    assert again.noise() is noise
