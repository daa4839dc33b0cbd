"""One frame as the detector's stages read it, and where they report.

A stage reads the frame's grey levels, white and local means from :class:`Frame`,
and writes its counts, survivors and detections to the frame's result and its
wall time to the frame's :class:`StageTimer`.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

from numpy.typing import NDArray

from marker_localizer.core import preprocessing
from marker_localizer.core.noise import NoiseModel, estimate_noise
from marker_localizer.core.result import DetectionResult


class StageTimer:
    """Context manager factory that records the wall time of a stage in ms."""

    def __init__(self, timings: dict[str, float]) -> None:
        self._timings = timings

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        """Time the ``with`` block as ``stage``, added to its earlier blocks' time."""
        start = time.perf_counter()
        try:
            yield
        finally:
            elapsed_ms = (time.perf_counter() - start) * 1000.0
            self._timings[stage] = self._timings.get(stage, 0.0) + elapsed_ms


@dataclass(frozen=True)
class Frame:
    """One frame as the default and the paper's checks read it, and where they report.

    Attributes:
        gray: (H, W) grey image, raw levels.
        full_scale: its white, in its own grey levels.
        gamma: the local means of Eq. (2), which normalise the rings and lower the
            contrast floors in shadow.
        result: where the stages write their counts, survivors and detections.
        timer: where they record their wall time.
        measured_noise: the frame's noise once :meth:`noise` has measured it (a
            second reading's frame holds the same list).
        slope_centred: whether the candidates read were centred with the light's
            slope (a second reading's, :meth:`reread`).
    """

    gray: NDArray[Any]
    full_scale: float
    gamma: preprocessing.LocalGamma
    result: DetectionResult
    timer: StageTimer
    measured_noise: list[NoiseModel] = field(default_factory=list)
    slope_centred: bool = False

    def noise(self) -> NoiseModel:
        """The frame's noise (:func:`estimate_noise`), measured on first use.

        A second reading (:meth:`reread`, a shadow divided out) shares it.
        """
        if not self.measured_noise:
            self.measured_noise.append(estimate_noise(self.gray, self.full_scale))
        return self.measured_noise[0]

    def reread(self) -> Frame:
        """The same frame reporting to a fresh result, its counts at zero, for a second reading.

        A second reading's counts describe candidates the first reading has counted;
        its candidates are centred with the light's slope (:meth:`SymmetryPath._recentre_lost`,
        :meth:`SymmetryPath._reread_shadowed`).
        """
        return replace(
            self,
            result=DetectionResult(counts=dict.fromkeys(self.result.counts, 0)),
            slope_centred=True,
        )
