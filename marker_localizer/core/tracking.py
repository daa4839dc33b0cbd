"""Tracking mode: detect near where markers are expected, the whole frame only when needed.

Between full-frame passes the image motion from the last frame is measured on
the markers. In a steady flight each track's constant-velocity prediction lies
within reach of the detector's reading of a known marker, which then confirms
the markers and measures the motion in one go. When it does not (a jolt of the
attitude moves the image by tens of pixels), a few anchor markers are found again
by matching their grey
patch from the last frame (normalised cross-correlation within ``max_motion_px``
of the prediction); after such a frame the patches alone measure the next few
(a jittery camera's predictions keep missing). Markers lie on the ground, a
plane, so the motion is a homography; fitted to the markers (a similarity or a
shift from fewer than four anchors), it maps every track's last position into
the frame. Each marker is then
confirmed by :meth:`Detector.locate`, started where the motion puts it: the
detector's stages from the centring on, its extent and line directions measured
on this frame, so that its position and its acceptance are a full pass's but for
the screening and the ground around it, which the pass that found it judged. A
marker it does not confirm is searched for in a small window, only as large as
the prediction's
error (``match_px``) plus the few pixels a marker's screening candidate may lie
off its centre; inside a window the detector runs exactly as on a full frame (it
samples the whole image; a window only bounds where candidates are screened).
Near the border, where a marker's plate is cut and what a full pass accepts
depends on the cut, :meth:`Detector.locate` does not confirm it: it is seeded at its
prediction into the detector's centring, verification and fit (a
:class:`SearchPlan`'s seeds). A marker's plate, here, is what the detector's
checks read around it: :attr:`Detector.support_radii` of its radius.
Markers come into view across the frame border, so the border is searched too,
but only on the sides whose content moves inward and only as deep as a marker's
plate plus that motion.

The rule for full-frame passes, precisely. A frame gets a full-frame pass

* when no marker is tracked (the first frame, after :meth:`MarkerTracker.reset`, and
  after a stamp that does not advance or a frame of another size, which reset);
* when ``full_frame_every - 1`` frames have been tracked since the last one
  (``phase`` fewer after the first pass that leaves tracks:
  :attr:`MarkerTracker.phase`);
* when there are more tracks than one pass takes on to the fit
  (:attr:`Detector.max_fitted`): a tiling of X's, where a tracked frame would
  confirm every track and add what its bands find, so that the tracks, and the
  time a frame takes, would grow from frame to frame;
* when the image motion cannot be measured: no anchor's patch is found again;
* when a marker is lost: the detector does not confirm a track whose predicted
  centre lies farther than its plate's half-width inside the frame, and the
  track's grey patch (cut when it was last confirmed) is not found within
  ``match_px`` of that prediction either. The prediction, or the marker, is
  then not where it was expected, and only a full pass can tell where it is.

The pass runs on the same frame and its detections replace the tracks, so a lost
marker costs time, not recall. A pass continues the tracks its detections lie
within ``max_motion_px`` of; where that is fewer than half of them, the common
shift most detections lie from their tracks by is the motion the prediction
missed, and the tracks continue from there: a flight that moves farther than
``max_motion_px`` a frame gets its tracks' velocities from the pass after its
first, and is tracked from then on. A track that is not confirmed but whose patch is
found where predicted is a marker in view that the detector rejects on this frame
(one at the acceptance threshold, which a full pass rejects as well): it costs no
pass and is searched for on up to ``max_missed_frames`` further frames before it
is dropped, so a marker that flickers at the threshold is found again when it
comes back. A full pass keeps the tracks it misses inside the frame in the same
way, whatever their patch shows (a marker at a shadow's edge, under glare), and
they are not lost again: the pass has shown that they cannot be detected there
now. Such a track is not confirmed by :meth:`Detector.locate`, which reads no
screening and no ground around it (a texture saddle that one pass accepted would
be confirmed frame after frame): the detector judges it in its window, as the pass
did. A track predicted outside the frame or within its plate's half-width of the
border that is not confirmed has left the view and ends without a pass.

What tracking cannot see until the next scheduled pass: a marker that becomes
detectable inside the frame without having been tracked (one at the threshold
that no pass has found, or one the detector first accepts well inside the
border).
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from marker_localizer.config import TrackerConfig, require_config
from marker_localizer.core import chroma
from marker_localizer.core.image import to_gray
from marker_localizer.core.pipeline import Detector
from marker_localizer.core.result import (
    Detection,
    DetectionResult,
    SearchPlan,
    extents,
    line_directions,
    positions,
    scores,
    strongest_first,
)
from marker_localizer.core.screening import non_maximum_suppression, parabolic_offset

#: Anchors whose patches measure the image motion: four fix a homography, the
#: fifth lets RANSAC leave out a patch matched on the wrong spot.
_ANCHORS = 5
#: Half-size of a track's patch, px: its plate, within these bounds (a smaller
#: patch is ambiguous in texture, a larger one costs time and meets perspective).
_PATCH_HALF_PX = (8, 24)
#: Lowest normalised cross-correlation of a track's patch with its new view; the
#: same marker a frame later correlates above 0.9, ground texture rarely above 0.5.
_MIN_PATCH_NCC = 0.7
#: An anchor is first looked for this close to its constant-velocity prediction,
#: px, and taken there when its patch correlates above ``_NEAR_MIN_PATCH_NCC`` at a
#: peak inside that search: in a steady flight the prediction holds to a pixel or
#: two, and this search costs a hundredth of one over ``max_motion_px``.
_NEAR_SEARCH_PX = 6.0
_NEAR_MIN_PATCH_NCC = 0.9
#: Frames whose motion the anchors' patches measure, without the tracks' fit at their
#: predictions first, once that fit has failed to measure it: under attitude jitter the
#: predictions miss by more than the fit's reach frame after frame, a failed fit costs
#: what a confirming one does, and the patches find the same markers (docs/speed.md,
#: "Tracking under the flight simulator's attitude jitter"). Then it is tried again.
_FIT_MOTION_RETRY_FRAMES = 4
#: Anchors lie at most this share of the frame's width (height) in from its left
#: and right (top and bottom) edges, whatever ``max_motion_px``: one set farther in
#: than ``max_motion_px`` plus its patch would be none at all once that motion
#: nears half the frame, and tracking would stop at the first frame the fit's
#: motion fails. In the central half an anchor stays in view after a motion of a
#: quarter frame in any direction, and after a larger one so do the anchors on
#: the side the content moves away from.
_ANCHOR_MARGIN_SHARE = 0.25
#: A marker's strongest screening candidate lies within this distance of the centre
#: the detector reports (measured on the speed benchmark's frames: windows of this
#: half-size around full-frame detections give back every one of them).
_CANDIDATE_OFFSET_PX = 2.0


@dataclass
class _Track:
    """One tracked marker.

    Attributes:
        xy: (2,) position on the last frame (detected, or predicted if missed), px.
        velocity: (2,) px per second; None until confirmed twice.
        detection: the last detection: extent, line angles, evidence.
        stamp_s: time of the last frame, s.
        missed: consecutive frames searched without a confirmation.
        patch: grey patch centred on round(xy) at the last confirmation.
        anchor: its patch measures the next frame's motion.
        missed_by_full_pass: a full pass has missed it since its last confirmation.
    """

    xy: NDArray[np.float64]
    velocity: NDArray[np.float64] | None
    detection: Detection
    stamp_s: float
    missed: int = 0
    patch: NDArray[np.float64] | None = None
    anchor: bool = False
    missed_by_full_pass: bool = False


@dataclass
class MarkerTracker:
    """Per-camera tracker around a :class:`Detector` (one per camera; not thread-safe).

    Attributes:
        detector: the detector whose settings apply to both kinds of pass.
        config: the tracking settings (:class:`~marker_localizer.config.TrackerConfig`:
            ``full_frame_every``, ``max_motion_px``, ``match_px``,
            ``max_missed_frames``; see the module's rule). With ``enabled`` false
            every frame gets a full-frame pass and no track is kept.
        phase: frames by which the first scheduled full pass comes early once a pass
            has left tracks (at the start, and after a reset), >= 0. A rig's cameras
            start together, and their full passes, several times a tracked frame's
            work each, would otherwise fall on the same frames of every camera from
            then on (:func:`staggered_phase` spreads them).

    Raises:
        TypeError: ``detector`` is not a :class:`Detector` or ``config`` not a
            :class:`~marker_localizer.config.TrackerConfig` (a dict of settings).
        ValueError: ``phase`` is not a whole number of frames, or is negative.
    """

    detector: Detector
    config: TrackerConfig = field(default_factory=TrackerConfig)
    phase: int = 0
    _tracks: list[_Track] = field(default_factory=list, init=False)
    _frames_since_full: int = field(default=0, init=False)
    _phase_pending: bool = field(default=True, init=False)
    _last_stamp_s: float = field(default=0.0, init=False)
    _frame_shape: tuple[int, ...] = field(default=(), init=False)
    _fit_motion_skips: int = field(default=0, init=False)
    _colour: NDArray[Any] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        # A mapping or a class failed later, on its first missing attribute.
        if not isinstance(self.detector, Detector):
            raise TypeError(f"MarkerTracker takes a Detector instance, not {self.detector!r:.80}")
        require_config(self.config, TrackerConfig, "MarkerTracker")
        # A NaN passed "< 0" and then counted frames; 2.5 frames is no frame.
        if isinstance(self.phase, bool) or not isinstance(self.phase, numbers.Integral):
            raise ValueError(f"phase must be a whole number of frames, got {self.phase!r:.80}")
        if self.phase < 0:
            raise ValueError(f"phase must be >= 0 frames, got {self.phase}")
        self.phase = int(self.phase)

    def reset(self) -> None:
        """Forget every track (after a jump in time or a parameter change)."""
        self._tracks = []
        self._frames_since_full = 0
        self._phase_pending = True
        self._fit_motion_skips = 0

    def update(self, image: NDArray[Any], stamp_s: float | None = None) -> DetectionResult:
        """Detect the markers of the next frame of this camera.

        Args:
            image: the frame, as for :meth:`Detector.detect`.
            stamp_s: capture time in seconds; frames are taken to be one second
                apart if omitted. A stamp that does not advance, or a frame of
                another size than the last (the camera's window or binning changed:
                the border bands would not cover what came into view), resets the
                tracks.

        Returns:
            The frame's result; ``counts["full_frame"]`` is 1 when the frame got a
            full-frame pass, ``counts["tracked"]`` the markers confirmed by tracking;
            ``timings_ms["registration"]`` is the anchor matching of a tracked frame.

        Raises:
            ImageError: as :meth:`Detector.detect`.
            ValueError: ``stamp_s`` is not finite.
        """
        stamp = self._last_stamp_s + 1.0 if stamp_s is None else float(stamp_s)
        if not np.isfinite(stamp):
            raise ValueError(f"stamp_s must be a finite time in seconds, got {stamp_s!r}")
        # Once, not per detector call: a strided view (a crop) is copied here.
        gray, _ = to_gray(image)
        # A colour frame's planes go to each detector call for its colour check.
        self._colour = image if chroma.is_colour(image) else None
        try:
            return self._update(gray, stamp)
        finally:
            self._colour = None

    def _update(self, gray: NDArray[Any], stamp: float) -> DetectionResult:
        """:meth:`update` on the frame's grey, its stamp checked."""
        if not self.config.enabled:
            self.reset()
            every = self.detector.detect(gray, colour=self._colour)
            every.counts["full_frame"] = 1
            every.counts["tracked"] = 0
            return every
        if self._tracks and (stamp <= self._last_stamp_s or gray.shape != self._frame_shape):
            self.reset()
        self._last_stamp_s, self._frame_shape = stamp, gray.shape
        # Measured on full passes too: it carries the tracks a pass misses.
        start = time.perf_counter()
        motion, located, predicted = None, None, None
        # More tracks than one pass fits are a tiling of X's, not markers: a tracked
        # frame would confirm every one and add what its bands find, frame after frame.
        crowded = len(self._tracks) > self.detector.max_fitted
        if self._tracks:
            predicted = self._predict(stamp)
            if not crowded:
                motion, located = self._measure_motion(gray, predicted)
        registration_ms = (time.perf_counter() - start) * 1000.0
        if motion is not None and self._frames_since_full + 1 < self.config.full_frame_every:
            result = self._track(gray, stamp, motion, located)
            if result is not None:
                result.timings_ms["registration"] = registration_ms
                self._frames_since_full += 1
                self._cut_patches(gray)
                return result
        result = self.detector.detect(gray, colour=self._colour)
        result.counts["full_frame"] = 1
        result.counts["tracked"] = 0
        self._adopt(gray, result, stamp, motion, predicted)
        self._frames_since_full = self.phase if self._phase_pending else 0
        self._phase_pending = self._phase_pending and not self._tracks
        self._cut_patches(gray)
        return result

    def _measure_motion(
        self, gray: NDArray[Any], predicted: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64] | None, DetectionResult | None]:
        """(3, 3) image motion from the last frame, and the tracks' fits if they measured it.

        The tracks' own fits first (:meth:`_motion_from_fit`); after they failed, the
        anchors' patches (:meth:`_register`) alone for a few frames. (None, None) when
        neither measures it.
        """
        motion, located = None, None
        if self._fit_motion_skips:
            self._fit_motion_skips -= 1
        else:
            motion, located = self._motion_from_fit(gray, predicted)
            if motion is None:
                self._fit_motion_skips = _FIT_MOTION_RETRY_FRAMES
        if motion is None:
            motion = self._register(gray, predicted)
        return motion, located

    def _predict(self, stamp: float) -> NDArray[np.float64]:
        """(N, 2) constant-velocity predictions; a track without velocity moves with the rest."""
        known = [t.velocity for t in self._tracks if t.velocity is not None]
        common = np.median(known, axis=0) if known else np.zeros(2)
        return np.array(
            [
                t.xy + (t.velocity if t.velocity is not None else common) * (stamp - t.stamp_s)
                for t in self._tracks
            ]
        ).reshape(-1, 2)

    def _motion_from_fit(
        self, gray: NDArray[Any], predicted: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64] | None, DetectionResult | None]:
        """(3, 3) image motion from the tracks' own fits, and those fits; (None, None) if unsure.

        ``predicted``: the tracks' constant-velocity predictions (:meth:`_predict`).

        In a steady flight the constant-velocity prediction lies within the fit's
        reach of each marker, and the fitted centres measure the motion better than
        matched patches, for the fit that confirms them anyway. Taken only when at
        least four tracks, and at least half of those the fit is started on, are
        confirmed within ``match_px`` of their prediction; else the prediction is
        off (a jolt, a turn) and the anchors' patches measure the motion.
        """
        fitted = self._fitted(self._leaving(predicted, gray.shape))
        if fitted.sum() < 4:
            return None, None
        located = self._locate_tracks(gray, predicted, fitted)
        centres = positions(located)
        owner = _associate(centres, predicted, fitted, self.config.match_px)
        confirmed = owner >= 0
        if confirmed.sum() < max(4, fitted.sum() / 2):
            return None, None
        sources = np.array([t.xy for t in self._tracks])[confirmed]
        targets = centres[owner[confirmed]]
        return _frame_motion(sources, targets, self.config.match_px), located

    def _fitted(self, leaving: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """(N,) the tracks :meth:`Detector.locate` may confirm at their predictions.

        ``leaving``: where the prediction lies within its plate of the border (:meth:`_leaving`).

        Not those near the border, where a full pass would not see the whole plate
        and what it accepts depends on the cut (:meth:`_track` seeds the detector
        there); nor those the last full pass missed: the fit reads no screening and
        no ground around a marker, so a texture saddle the pass accepted once and
        then rejected would be confirmed by it frame after frame. The detector
        judges those in their windows, as a full pass does.
        """
        fitted: NDArray[np.bool_] = ~leaving & ~self._missed_by_full_pass()
        return fitted

    def _missed_by_full_pass(self) -> NDArray[np.bool_]:
        """(N,) the tracks a full pass has missed since they were last confirmed."""
        return np.array([t.missed_by_full_pass for t in self._tracks], dtype=bool)

    def _locate_tracks(
        self, gray: NDArray[Any], predicted: NDArray[np.float64], fitted: NDArray[np.bool_]
    ) -> DetectionResult:
        """:meth:`Detector.locate` of the ``fitted`` tracks, at their predictions."""
        known = [t.detection for t, seen in zip(self._tracks, fitted, strict=True) if seen]
        return self.detector.locate(
            gray,
            predicted[fitted],
            extents(known),
            line_directions(known),
            np.array([d.evidence for d in known]),
            colour=self._colour,
        )

    def _register(
        self, gray: NDArray[Any], predicted: NDArray[np.float64]
    ) -> NDArray[np.float64] | None:
        """(3, 3) image motion from the last frame, measured on the anchors; None if none found.

        ``predicted``: the tracks' constant-velocity predictions, where the search starts.
        """
        sources, targets = [], []
        for track, prediction in zip(self._tracks, predicted, strict=True):
            if not track.anchor or track.patch is None:
                continue
            found = self._match_patch(
                gray, track.patch, prediction, _NEAR_SEARCH_PX, _NEAR_MIN_PATCH_NCC, interior=True
            )
            if found is None:
                found = self._match_patch(gray, track.patch, prediction, self.config.max_motion_px)
            if found is not None:
                # The patch was cut at the rounded centre: restore the fraction.
                sources.append(track.xy)
                targets.append(found + track.xy - np.round(track.xy))
        if not sources:
            return None
        return _frame_motion(np.array(sources), np.array(targets), self.config.match_px)

    @staticmethod
    def _match_patch(
        gray: NDArray[Any],
        patch: NDArray[np.float64],
        prediction: NDArray[np.float64],
        search_px: float,
        min_ncc: float = _MIN_PATCH_NCC,
        interior: bool = False,
    ) -> NDArray[np.float64] | None:
        """Centre of the best match of ``patch`` within ``search_px`` of ``prediction``.

        None when its correlation is below ``min_ncc`` or, with ``interior``, when it
        lies on the search's edge (the best match may then lie beyond it).
        """
        height, width = gray.shape
        half = patch.shape[0] // 2
        reach = half + int(np.ceil(search_px))
        cx, cy = np.round(prediction).astype(np.int64)
        x0, y0 = max(cx - reach, 0), max(cy - reach, 0)
        x1, y1 = min(cx + reach + 1, width), min(cy + reach + 1, height)
        if x1 - x0 < patch.shape[1] or y1 - y0 < patch.shape[0]:
            return None
        search = gray[y0:y1, x0:x1]
        # matchTemplate takes 8-bit or float32 images only.
        ncc = cv2.matchTemplate(search.astype(patch.dtype, copy=False), patch, cv2.TM_CCOEFF_NORMED)
        row, col = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
        if not ncc[row, col] >= min_ncc:
            return None
        last_row, last_col = ncc.shape[0] - 1, ncc.shape[1] - 1
        if interior and not (0 < row < last_row and 0 < col < last_col):
            return None
        dx = float(parabolic_offset(*ncc[row, col - 1 : col + 2])) if 0 < col < last_col else 0.0
        dy = float(parabolic_offset(*ncc[row - 1 : row + 2, col])) if 0 < row < last_row else 0.0
        return np.array([x0 + col + dx + half, y0 + row + dy + half])

    def _track(
        self,
        gray: NDArray[Any],
        stamp: float,
        motion: NDArray[np.float64],
        located: DetectionResult | None = None,
    ) -> DetectionResult | None:
        """Confirm the tracks where the motion puts them, search the border bands.

        ``located``: the fits that measured the motion, if they did (they are not
        run again). None if the frame needs a full pass.
        """
        shape = gray.shape
        height, width = shape
        corrected = _transform(motion, np.array([t.xy for t in self._tracks]))
        inside = (
            (corrected[:, 0] >= 0)
            & (corrected[:, 0] <= width - 1)
            & (corrected[:, 1] >= 0)
            & (corrected[:, 1] <= height - 1)
        )
        bands, interior = self._border_bands(shape, motion)
        # First each marker read again from where the motion puts it, to the same centre
        # as a full pass (its cost a marker: the README's speed table).
        leaving = self._leaving(corrected, shape)
        fitted = self._fitted(leaving)
        if located is None:
            located = self._locate_tracks(gray, corrected, fitted)
        confirmed = _associate(positions(located), corrected, fitted, self.config.match_px) >= 0
        # Then the detector in a window around each marker the fit did not confirm
        # (a prediction off by more than the fit's reach, or a marker changed) or was
        # not started on (one the last full pass missed).
        retry = inside & ~leaving & ~confirmed
        # A marker whose plate the border cuts is not fitted: what a full pass accepts
        # there depends on the cut. It takes the full pass's stages from the centring
        # on, seeded at its prediction, unless a band screens it anyway.
        x0, y0, x1, y1 = interior
        seeded = (
            inside
            & leaving
            & (corrected[:, 0] >= x0)
            & (corrected[:, 0] < x1)
            & (corrected[:, 1] >= y0)
            & (corrected[:, 1] < y1)
        )
        regions = bands
        if retry.any():
            half = self.config.match_px + _CANDIDATE_OFFSET_PX
            around = np.hstack([corrected[retry] - half, corrected[retry] + half + 1])
            windows = _merge_overlapping(self._snap(around, shape))
            # Band and window areas are searched once: windows are cut to the interior.
            windows[:, :2] = np.maximum(windows[:, :2], interior[:2])
            windows[:, 2:] = np.minimum(windows[:, 2:], interior[2:])
            windows = windows[(windows[:, 2] > windows[:, 0]) & (windows[:, 3] > windows[:, 1])]
            regions = np.vstack([windows, bands])
        parts = [located]
        if len(regions) or seeded.any():
            # A marker the fit confirmed is not verified again where a band or window
            # covers it (the bands reach as deep as the plates of markers come in).
            parts.append(
                self.detector.detect(
                    gray,
                    SearchPlan(regions, positions(located), corrected[seeded]),
                    colour=self._colour,
                )
            )
        result = _combine(parts, self.detector.config.merge_radius_px)
        found = positions(result)
        owner = _associate(found, corrected, inside, self.config.match_px)
        missed = owner < 0
        kept = self._kept(gray, corrected, missed & ~leaving)
        excused = self._missed_by_full_pass()
        if (missed & ~leaving & ~kept & ~excused).any():
            return None  # a marker is lost
        tracks = []
        for track, index, prediction, keep in zip(
            self._tracks, owner, corrected, kept, strict=True
        ):
            if index >= 0:
                tracks.append(_confirmed(track, result.detections[index], stamp))
            elif keep:
                tracks.append(_coasting(track, prediction, stamp, track.missed_by_full_pass))
        claimed = np.zeros(len(found), dtype=bool)
        claimed[owner[owner >= 0]] = True
        tracks += [
            _Track(found[k].copy(), None, result.detections[k], stamp)
            for k in np.flatnonzero(~claimed)
        ]
        self._tracks = tracks
        result.counts["full_frame"] = 0
        result.counts["tracked"] = int((~missed).sum())
        return result

    def _border_bands(
        self, shape: tuple[int, ...], motion: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Bands along the frame border through which markers can have come into view.

        A marker whose plate was cut by the border on the last frame and is whole now
        has its centre within its plate's half-width plus the inward motion of the
        content at that side. A side is searched when that motion, plus the error
        ``match_px``, is positive (all four sides while the image is still).

        Args:
            shape: the frame's shape.
            motion: (3, 3) image motion from the last frame.

        Returns:
            (bands, interior): (K, 4) windows (x0, y0, x1, y1), K <= 4, that tile the
            searched border without overlap, and the (4,) rectangle they leave free.
        """
        height, width = shape[:2]
        reach = self.detector.support_radii * self.detector.config.marker_radius_max_px
        # The last frame's border, three points a side, moved by the motion: the
        # content's inward displacement at the top, bottom, left and right sides.
        t = np.array([0.0, 0.5, 1.0])
        zero, one = np.zeros(3), np.ones(3)
        sides = [((t, zero), 1, 1), ((t, one), 1, -1), ((zero, t), 0, 1), ((one, t), 0, -1)]
        inward = np.zeros(4)
        for side, ((u, v), axis, sign) in enumerate(sides):
            border = np.stack([u * (width - 1), v * (height - 1)], axis=1)
            inward[side] = np.max(sign * (_transform(motion, border) - border)[:, axis])
        # The whole measured motion, not only max_motion_px: that bounds the error of
        # the constant-velocity prediction, and a fast flight moves the image further.
        depth = np.where(
            inward + self.config.match_px > 0,
            np.minimum(reach + np.maximum(inward, 0.0) + self.config.match_px, max(height, width)),
            0.0,
        )
        lattice = self.detector.region_lattice_px
        top, left = (np.ceil(depth[[0, 2]] / lattice) * lattice).astype(np.int64)
        bottom = int(np.floor((height - depth[1]) / lattice) * lattice) if depth[1] else height
        right = int(np.floor((width - depth[3]) / lattice) * lattice) if depth[3] else width
        top, left = min(top, height), min(left, width)
        bottom, right = max(bottom, top), max(right, left)
        bands = np.array(
            [
                [0, 0, width, top],
                [0, bottom, width, height],
                [0, top, left, bottom],
                [right, top, width, bottom],
            ]
        )
        bands = bands[(bands[:, 2] > bands[:, 0]) & (bands[:, 3] > bands[:, 1])]
        return bands, np.array([left, top, right, bottom])

    def _snap(self, windows: NDArray[np.float64], shape: tuple[int, ...]) -> NDArray[np.int64]:
        """(K, 4) float windows grown to the lattice and clipped to the frame, int64."""
        height, width = shape[:2]
        lattice = self.detector.region_lattice_px
        snapped = (
            np.hstack(
                [np.floor(windows[:, :2] / lattice), np.ceil(windows[:, 2:] / lattice)]
            ).astype(np.int64)
            * lattice
        )
        return np.clip(snapped, 0, [width, height, width, height]).reshape(-1, 4)

    def _adopt(
        self,
        gray: NDArray[Any],
        result: DetectionResult,
        stamp: float,
        motion: NDArray[np.float64] | None,
        velocity_predicted: NDArray[np.float64] | None,
    ) -> None:
        """Replace the tracks by a full pass's detections, continuing those matching a track.

        ``velocity_predicted``: the tracks' constant-velocity predictions, used where
        no motion was measured (None without tracks).
        """
        tracks = [_Track(np.array([d.x, d.y]), None, d, stamp) for d in result]
        if velocity_predicted is not None:
            found = positions(result)
            if motion is None:
                predicted = velocity_predicted
            else:
                predicted = _transform(motion, np.array([t.xy for t in self._tracks]))
            everyone = np.ones(len(predicted), bool)
            shift_radius = self.config.max_motion_px / 2.0
            near = _associate(found, predicted, everyone, shift_radius)
            if (near >= 0).sum() < min(len(found), len(predicted)) / 2.0:
                # The prediction missed most markers by more than the shift's vote radius:
                # all of the motion, where the tracks have no velocity yet and a flight
                # moves farther than max_motion_px a frame (the anchors' patches then
                # match their neighbours, as alike as markers are), and the patches'
                # motion is wrong too: markers twice that motion apart still meet a
                # prediction within max_motion_px. Only then: on a lattice of X's a shift
                # by its period would win as many votes.
                predicted = predicted + _common_shift(found, predicted, shift_radius)
            owner = _associate(found, predicted, everyone, self.config.max_motion_px)
            # Without a measured motion, a missed track's position is a guess: it ends.
            inside = ~self._leaving(predicted, gray.shape) & (motion is not None)
            for track, index, prediction, keep in zip(
                self._tracks, owner, predicted, inside, strict=True
            ):
                if index >= 0 and stamp > track.stamp_s:
                    tracks[index] = _confirmed(track, result.detections[index], stamp)
                elif index < 0 and keep and track.missed < self.config.max_missed_frames:
                    tracks.append(_coasting(track, prediction, stamp, missed_by_full_pass=True))
        self._tracks = tracks

    def _kept(
        self, gray: NDArray[Any], predicted: NDArray[np.float64], candidates: NDArray[np.bool_]
    ) -> NDArray[np.bool_]:
        """(N,) True for the missed tracks to search again on the next frame.

        ``candidates`` are the missed tracks whose prediction lies inside the frame,
        away from the border by its plate's half-width. One is kept for up to
        ``max_missed_frames`` frames while a full pass has missed it too or its patch
        is found within ``match_px`` of the prediction (a marker in view that the
        detector rejects).
        """
        kept = np.zeros(len(self._tracks), dtype=bool)
        for k in np.flatnonzero(candidates):
            track = self._tracks[k]
            kept[k] = track.missed < self.config.max_missed_frames and (
                track.missed_by_full_pass
                or (
                    track.patch is not None
                    and self._match_patch(gray, track.patch, predicted[k], self.config.match_px)
                    is not None
                )
            )
        return kept

    def _leaving(self, predicted: NDArray[np.float64], shape: tuple[int, ...]) -> NDArray[np.bool_]:
        """(N,) True where a track's predicted centre is within its plate of the border or out."""
        height, width = shape[:2]
        border_distance = np.minimum(
            np.minimum(predicted[:, 0], width - 1 - predicted[:, 0]),
            np.minimum(predicted[:, 1], height - 1 - predicted[:, 1]),
        )
        radius = np.array([t.detection.radius_px for t in self._tracks])
        return cast("NDArray[np.bool_]", border_distance < self.detector.support_radii * radius)

    def _cut_patches(self, gray: NDArray[Any]) -> None:
        """Cut the patch of every marker confirmed on this frame; mark a few as anchors.

        The anchors are large markers (the most distinct patches) far apart (the
        motion's roll, scale and perspective are then fixed best) whose patches stay
        in view after the largest unforeseen motion, ``max_motion_px``, or that lie
        in the frame's central half where that motion exceeds a quarter frame
        (:data:`_ANCHOR_MARGIN_SHARE`).
        """
        height, width = gray.shape
        motion = math.ceil(self.config.max_motion_px)
        reach_x = min(motion, int(_ANCHOR_MARGIN_SHARE * width))
        reach_y = min(motion, int(_ANCHOR_MARGIN_SHARE * height))
        candidates = []
        for track in self._tracks:
            track.anchor = False
            if track.missed:
                continue  # its patch is the one from its last confirmation
            plate = self.detector.support_radii * track.detection.radius_px
            # Python scalars: numpy's per-call cost on scalars is a millisecond a frame.
            half = min(max(math.ceil(plate), _PATCH_HALF_PX[0]), _PATCH_HALF_PX[1])
            cx, cy = round(float(track.xy[0])), round(float(track.xy[1]))
            track.patch = None
            if half <= cx < width - half and half <= cy < height - half:
                patch = gray[cy - half : cy + half + 1, cx - half : cx + half + 1]
                # matchTemplate takes 8-bit or float32 images only.
                track.patch = patch.copy() if patch.dtype == np.uint8 else patch.astype(np.float32)
            margin_x, margin_y = half + reach_x, half + reach_y
            if margin_x <= cx < width - margin_x and margin_y <= cy < height - margin_y:
                candidates.append((track, cx, cy))
        if not candidates:
            return
        candidates.sort(key=lambda c: -c[0].detection.radius_px)
        candidates = candidates[: max(_ANCHORS, len(candidates) // 2)]
        # Farthest-point choice: each next anchor farthest from those chosen.
        points = np.array([(cx, cy) for _, cx, cy in candidates], dtype=np.float64)
        spread = np.hypot(*(points - points[0]).T)
        chosen = [0]
        while len(chosen) < min(_ANCHORS, len(points)):
            chosen.append(int(np.argmax(spread)))
            spread = np.minimum(spread, np.hypot(*(points - points[chosen[-1]]).T))
        for k in chosen:
            candidates[k][0].anchor = True


def staggered_phase(camera_index: int, n_cameras: int, full_frame_every: int) -> int:
    """The :attr:`MarkerTracker.phase` of camera ``camera_index`` of ``n_cameras``.

    The cameras' phases spread evenly over ``full_frame_every``, so that their
    scheduled full passes fall on different frames: with 5 cameras and a pass
    every 10 frames, one camera's pass every other frame instead of all five on
    every tenth.
    """
    return camera_index * full_frame_every // max(n_cameras, 1)


def _confirmed(track: _Track, detection: Detection, stamp: float) -> _Track:
    """The track continued by ``detection`` at ``stamp``."""
    xy = np.array([detection.x, detection.y])
    velocity = (xy - track.xy) / (stamp - track.stamp_s)
    return _Track(xy, velocity, detection, stamp)


def _coasting(
    track: _Track, prediction: NDArray[np.float64], stamp: float, missed_by_full_pass: bool
) -> _Track:
    """The track carried to ``stamp`` at its predicted position, one more frame missed."""
    return _Track(
        prediction,
        track.velocity,
        track.detection,
        stamp,
        track.missed + 1,
        track.patch,
        missed_by_full_pass=missed_by_full_pass,
    )


#: Fewest predictions that must agree on a shift for :func:`_common_shift` to take it:
#: one or two markers meeting others' positions by chance are no image motion.
_MIN_SHIFT_SUPPORT = 3


def _common_shift(
    points: NDArray[np.float64], predicted: NDArray[np.float64], radius_px: float
) -> NDArray[np.float64]:
    """(2,) the image shift most predictions missed their detections by; zero if none does.

    Every displacement from a prediction to a detection is a vote; the shift is the
    median of the densest cluster of votes (within ``radius_px`` of one of them),
    taken where at least half the markers of the fewer side (and
    :data:`_MIN_SHIFT_SUPPORT`) agree on it.
    """
    if not len(points) or not len(predicted):
        return np.zeros(2)
    votes = (points[None, :, :] - predicted[:, None, :]).reshape(-1, 2)
    support = cKDTree(votes).query_ball_point(votes, radius_px, return_length=True)
    best = int(np.argmax(support))
    if support[best] < max(_MIN_SHIFT_SUPPORT, min(len(points), len(predicted)) / 2.0):
        return np.zeros(2)
    near = np.linalg.norm(votes - votes[best], axis=1) <= radius_px
    shift: NDArray[np.float64] = np.median(votes[near], axis=0)
    return shift


def _associate(
    points: NDArray[np.float64],
    predicted: NDArray[np.float64],
    searched: NDArray[np.bool_],
    gate_px: float,
) -> NDArray[np.int64]:
    """(N,) index of the point continuing each searched prediction, -1 for none.

    Each point continues at most one track, the one predicted closest to it.
    """
    owner = np.full(len(predicted), -1, dtype=np.int64)
    if not len(points) or not len(predicted):
        return owner
    distance, nearest = cKDTree(points).query(predicted, distance_upper_bound=gate_px)
    taken = np.zeros(len(points), dtype=bool)
    # Of predictions as near one point, the first listed takes it.
    for index in np.argsort(distance, kind="stable"):
        if not np.isfinite(distance[index]):
            break  # the rest are farther than the gate too
        if searched[index] and not taken[nearest[index]]:
            owner[index] = nearest[index]
            taken[nearest[index]] = True
    return owner


def _merge_overlapping(windows: NDArray[np.int64]) -> NDArray[np.int64]:
    """Replace overlapping windows by their bounding box until none overlap."""
    while len(windows) > 1:
        overlap = (
            (windows[:, None, 0] < windows[None, :, 2])
            & (windows[None, :, 0] < windows[:, None, 2])
            & (windows[:, None, 1] < windows[None, :, 3])
            & (windows[None, :, 1] < windows[:, None, 3])
        )
        if overlap.sum() == len(windows):
            break  # each overlaps only itself
        count, label = connected_components(overlap, directed=False)
        if count == len(windows):
            break
        windows = np.array(
            [
                np.r_[windows[label == k, :2].min(axis=0), windows[label == k, 2:].max(axis=0)]
                for k in range(count)
            ]
        )
    return windows.reshape(-1, 4)


def _combine(results: list[DetectionResult], separation_px: float) -> DetectionResult:
    """One result from the calls of a tracked frame: summed counts and times.

    A marker on the edge between a window and a band can be found by both calls;
    the weaker copy is merged away as the detector's own last suppression would.
    """
    combined = DetectionResult()
    for part in results:
        combined.detections += part.detections
        for key, count in part.counts.items():
            combined.counts[key] = combined.counts.get(key, 0) + count
        for stage, ms in part.timings_ms.items():
            combined.timings_ms[stage] = combined.timings_ms.get(stage, 0.0) + ms
    score = scores(combined)
    keep = non_maximum_suppression(positions(combined), score, separation_px)
    combined.counts["merged_duplicates"] = combined.counts.get("merged_duplicates", 0) + int(
        (~keep).sum()
    )
    order = strongest_first(np.flatnonzero(keep), score)
    combined.detections = [combined.detections[k] for k in order]
    combined.counts["accepted"] = len(combined.detections)
    return combined


def _frame_motion(
    source: NDArray[np.float64], target: NDArray[np.float64], tolerance_px: float
) -> NDArray[np.float64]:
    """(3, 3) map taking the (N, 2) source points to the targets.

    A homography from four pairs or more (the ground plane seen from two poses),
    fitted by RANSAC so that a patch matched on the wrong spot is left out; else a
    least-squares similarity (shift, roll, scale) from two or three, a shift from one.
    """
    if len(source) >= 4:
        homography, _ = cv2.findHomography(source, target, cv2.RANSAC, tolerance_px)
        if homography is not None:
            return np.asarray(homography, dtype=np.float64)
    if len(source) == 1:
        shift = target[0] - source[0]
        return np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]], [0.0, 0.0, 1.0]])
    # Least-squares similarity x' = s R x + t in complex form: z' = a z + b.
    z = source[:, 0] + 1j * source[:, 1]
    w = target[:, 0] + 1j * target[:, 1]
    zc, wc = z - z.mean(), w - w.mean()
    a = (np.conj(zc) @ wc) / max(float(np.real(np.conj(zc) @ zc)), 1e-12)
    b = w.mean() - a * z.mean()
    return np.array([[a.real, -a.imag, b.real], [a.imag, a.real, b.imag], [0.0, 0.0, 1.0]])


def _transform(motion: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 2) points mapped by the (3, 3) projective ``motion``."""
    return cast(
        "NDArray[np.float64]",
        cv2.perspectiveTransform(points.reshape(-1, 1, 2), motion).reshape(-1, 2),
    )
