"""Tracking mode: detect near where markers are expected, the whole frame only when needed.

Between full-frame passes every tracked marker is predicted with a constant
velocity, the prediction is corrected for the attitude jitter that moves the
whole image by tens of pixels between frames (measured on a few anchor markers
searched in large windows), and each marker is searched for in a small window
around it. Inside the windows the detector runs exactly as on a full frame, so
a tracked marker's position, score and sigma are those a full pass would give.
Markers that come into view can only do so across the frame border, so a band
along the border is searched on every frame as well. A full-frame pass
runs every ``full_frame_every`` frames, while any track has no velocity yet, and
at once (on the same frame) when a tracked marker is not confirmed inside the
frame: a lost marker costs time, never recall.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from marker_localizer.core.pipeline import DetectionResult, Detector

#: Half-width of a marker's plate in marker radii (the plates of the renderer and of
#: printed targets extend a quarter radius beyond the X).
PLATE_HALF_WIDTH = 1.25


@dataclass
class _Track:
    xy: np.ndarray  # (2,) last position, px
    velocity: np.ndarray | None  # (2,) px per second; None until seen twice
    radius_px: float
    stamp_s: float


@dataclass
class MarkerTracker:
    """Per-camera tracker around a :class:`Detector` (one per camera; not thread-safe).

    Attributes:
        detector: the detector whose settings apply to both kinds of pass.
        full_frame_every: a full-frame pass every this many frames (1 = always).
        max_motion_px: the largest image motion of a marker between two frames;
            sets how far a new track is associated and the width of the border band.
        match_px: once the anchors have corrected the predictions, a marker must
            lie within this distance (plus half its radius) of its prediction.
    """

    detector: Detector
    full_frame_every: int = 10
    max_motion_px: float = 64.0
    match_px: float = 3.0
    _tracks: list[_Track] = field(default_factory=list)
    _frames_since_full: int = 0
    _last_stamp_s: float = 0.0

    def reset(self) -> None:
        """Forget every track (after a jump in time or a parameter change)."""
        self._tracks = []
        self._frames_since_full = 0

    def update(self, image: np.ndarray, stamp_s: float | None = None) -> DetectionResult:
        """Detect the markers of the next frame of this camera.

        Args:
            image: the frame, as for :meth:`Detector.detect`.
            stamp_s: capture time in seconds; frames are taken to be one second
                apart if omitted. A stamp that does not advance resets the tracks.

        Returns:
            The frame's result; ``counts["full_frame"]`` is 1 when the frame got a
            full-frame pass, ``counts["tracked"]`` the markers confirmed by tracking.
        """
        stamp = self._last_stamp_s + 1.0 if stamp_s is None else float(stamp_s)
        if self._tracks and stamp <= self._last_stamp_s:
            self.reset()
        self._last_stamp_s = stamp
        ready = bool(self._tracks) and all(t.velocity is not None for t in self._tracks)
        if ready and self._frames_since_full + 1 < self.full_frame_every:
            result = self._track(image, stamp)
            if result is not None:
                self._frames_since_full += 1
                return result
        result = self.detector.detect(image)
        result.counts["full_frame"] = 1
        result.counts["tracked"] = 0
        self._adopt(result, stamp)
        self._frames_since_full = 0
        return result

    def _predict(self, stamp: float) -> np.ndarray:
        return np.array(
            [
                t.xy + (t.velocity if t.velocity is not None else 0.0) * (stamp - t.stamp_s)
                for t in self._tracks
            ]
        ).reshape(-1, 2)

    def _border_bands(self, shape: tuple[int, ...], motion: np.ndarray) -> np.ndarray:
        """Windows along the frame border through which markers can have come into view.

        Args:
            shape: the frame's shape.
            motion: (N, 2) displacement of every track since the last frame, px
                (anchor correction included).

        Returns:
            (K, 4) windows, K <= 4: only the sides the image content moves away from
            (new ground enters there); all four while the content is about still.
        """
        height, width = shape[:2]
        step = float(np.max(np.linalg.norm(motion, axis=1))) if len(motion) else 0.0
        # A marker whose plate was cut by the border last frame and is whole now has
        # its centre within its plate's half-width plus one frame's motion of the
        # border; the match tolerance covers the motion's own error.
        reach = PLATE_HALF_WIDTH * self.detector.config.marker_radius_max_px
        band = int(np.ceil(min(step, self.max_motion_px) + reach + self.match_px))
        dx, dy = np.mean(motion, axis=0) if len(motion) else (0.0, 0.0)
        sides = [
            (dy > -self.match_px, [0, 0, width, band]),
            (dy < self.match_px, [0, height - band, width, height]),
            (dx > -self.match_px, [0, 0, band, height]),
            (dx < self.match_px, [width - band, 0, width, height]),
        ]
        bands = np.array([box for inflow, box in sides if inflow]).reshape(-1, 4)
        # On a frame narrower than two bands they overlap: clip them to the frame.
        return np.clip(bands, 0, [width, height, width, height])

    def _windows(self, centres: np.ndarray, half: np.ndarray) -> np.ndarray:
        """(N, 4) windows (x0, y0, x1, y1) of half-size ``half`` around ``centres``."""
        return np.hstack(
            [np.floor(centres - half[:, None]), np.ceil(centres + half[:, None]) + 1]
        ).astype(np.int64)

    def _track(self, image: np.ndarray, stamp: float) -> DetectionResult | None:
        """Search every track near its prediction and the border bands; None if one was lost.

        The prediction is corrected in two steps: up to three anchor tracks (the
        largest markers, spread over the frame) are searched within the full motion
        bound, and the similarity transform that takes their predictions to their
        detections (attitude jitter: shift, roll, scale) is applied to every other
        prediction, which then needs only a small window.
        """
        height, width = image.shape[:2]
        predicted = self._predict(stamp)
        radius = np.array([t.radius_px for t in self._tracks])
        margin = 1.25 * radius
        # Markers predicted to have left the frame end their tracks without a search.
        in_view = (
            (predicted[:, 0] > margin)
            & (predicted[:, 0] < width - 1 - margin)
            & (predicted[:, 1] > margin)
            & (predicted[:, 1] < height - 1 - margin)
        )
        if not in_view.any():
            return None
        index = np.flatnonzero(in_view)
        anchors = index[np.argsort(-radius[index])[:3]]
        anchor_result = self.detector.detect(
            image,
            regions=self._windows(predicted[anchors], 1.5 * radius[anchors] + self.max_motion_px),
        )
        found = anchor_result.as_array()
        if len(found) < len(anchors):
            return None
        distance, owner = cKDTree(found[:, :2]).query(predicted[anchors])
        if (distance > self.max_motion_px + 0.5 * radius[anchors]).any():
            return None
        corrected = _apply_similarity(predicted[anchors], found[owner, :2], predicted)
        motion = corrected - np.array([t.xy for t in self._tracks])
        reach = self.match_px + 0.5 * radius
        regions = np.vstack(
            [
                self._windows(corrected[in_view], 1.5 * radius[in_view] + reach[in_view]),
                self._border_bands(image.shape, motion),
            ]
        )
        result = self.detector.detect(image, regions=regions)
        found = result.as_array()
        if not len(found):
            return None
        distance, _ = cKDTree(found[:, :2]).query(corrected[in_view])
        if (distance > reach[in_view]).any():
            return None
        for stage, ms in anchor_result.timings_ms.items():
            result.timings_ms[stage] = result.timings_ms.get(stage, 0.0) + ms
        result.counts["full_frame"] = 0
        result.counts["tracked"] = int(in_view.sum())
        self._adopt(result, stamp, corrected)
        return result

    def _adopt(
        self, result: DetectionResult, stamp: float, predicted: np.ndarray | None = None
    ) -> None:
        """Start tracks from a frame's detections, continuing those matching a track."""
        tracks = []
        if self._tracks:
            predicted = self._predict(stamp) if predicted is None else predicted
            tree = cKDTree(predicted)
        for d in result.detections:
            xy = np.array([d.x, d.y])
            velocity = None
            if self._tracks:
                distance, index = tree.query(xy)
                old = self._tracks[int(index)]
                # A track without velocity may have moved anywhere within the motion bound.
                gate = self.max_motion_px + 0.5 * old.radius_px
                if distance <= gate and stamp > old.stamp_s:
                    velocity = (xy - old.xy) / (stamp - old.stamp_s)
            tracks.append(_Track(xy, velocity, d.radius_px, stamp))
        self._tracks = tracks


def _apply_similarity(source: np.ndarray, target: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map ``points`` by the similarity (or, from one pair, the shift) taking source to target."""
    if len(source) == 1:
        return points + (target[0] - source[0])
    # Least-squares similarity x' = s R x + t in complex form: z' = a z + b.
    z = source[:, 0] + 1j * source[:, 1]
    w = target[:, 0] + 1j * target[:, 1]
    zc, wc = z - z.mean(), w - w.mean()
    a = (np.conj(zc) @ wc) / max(float(np.real(np.conj(zc) @ zc)), 1e-12)
    mapped = a * (points[:, 0] + 1j * points[:, 1] - z.mean()) + w.mean()
    return np.stack([mapped.real, mapped.imag], axis=1)
