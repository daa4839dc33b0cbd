"""Calibrating the decision: its score's weights, and the score's false-alarm rate.

``marker-localizer bench calibrate`` prints the constants of
:mod:`marker_localizer.core.decision` that come from data, and the figures they
come from:

* ``SCORE_WEIGHTS`` / ``SCORE_BIAS``: a logistic regression of markers against
  ground texture on the decision's evidence (:func:`decision.score_features`).
  Markers are the candidates whose fit ends within :data:`MATCH_PX` of a rendered
  marker; texture is every candidate farther than :data:`CLEAR_PX` from all of
  them, on the package's rendered families (ground photographs, look-alikes) and
  on the real marker-free aerial frames. The two classes weigh equally.
* ``FALSE_ALARM_TAIL``, for the score as :mod:`~marker_localizer.core.decision`
  now weighs it: on real ground without markers (the marker-free aerial frames,
  and the real boards' backgrounds: ValidationBoof's photographs outside each
  board's area, :func:`real_data.board_mask`), at the smallest
  radius range the package is asked for (3-30 px), the false points per megapixel
  that pass every other test of the decision, as a function of the score: the
  :data:`TAIL_POINTS` highest scores' excess over the next one is exponential
  (peaks over threshold), with their mean excess as its scale. A table of the
  counts at a grid of scores is printed beside it, to check the tail against.

The rendered frames use their own seeds (:data:`TRAINING_SEED`), not those of
``bench accuracy``; the independent renderer's frames are never read here.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from marker_localizer import Detector, DetectorConfig
from marker_localizer.bench import real_data
from marker_localizer.bench.accuracy import families
from marker_localizer.bench.runner import Report, add_json_option, run_and_save
from marker_localizer.core import decision

#: First seed of the rendered training frames: far from ``bench accuracy``'s.
TRAINING_SEED = 10_000
#: Rendered frames per family (a quick run: one).
FRAMES_PER_FAMILY = 4
#: A candidate whose fit ends this close to a rendered marker is that marker, px.
MATCH_PX = 1.0
#: ... and one farther than this from every marker is ground texture, px.
CLEAR_PX = 3.0
#: The radius range of the false-alarm rate: the smallest the package is asked for.
CALIBRATION_RADIUS_PX = (3.0, 30.0)
#: L2 penalty of the logistic weights (on standardised features): a nudge against
#: weights no data pins down.
_L2 = 1e-3
#: Scores at which the false-alarm rate is tabulated.
_SCORE_GRID = np.arange(-2.0, 12.01, 0.5)
#: Highest texture scores the tail is fitted to: enough that their mean excess
#: (the exponential's scale) is known to ~20 %, few enough to be the tail.
TAIL_POINTS = 25


def _verdicts(image: np.ndarray, radius_range: tuple[float, float]) -> decision.Verdicts:
    """Every candidate the decision sees on ``image``, with the threshold out of the way."""
    config = DetectorConfig(
        marker_radius_min_px=radius_range[0],
        marker_radius_max_px=radius_range[1],
        refinement="template",
    )
    result = Detector(config).detect(image)
    assert result.verdicts is not None
    return result.verdicts


def _rendered(quick: bool) -> Iterator[tuple[np.ndarray, tuple[float, float], np.ndarray]]:
    """(image, radius range, marker centres) of the rendered training frames."""
    for family in families():
        if family.key == "e" or family.variant:
            continue
        for k in range(1 if quick else FRAMES_PER_FAMILY):
            scene = family.render(TRAINING_SEED + k)
            yield scene.image, family.radius_range, scene.centres


def collect(
    verdicts: decision.Verdicts,
    min_radius_px: float,
    truth: np.ndarray,
    excluded: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features, label, eligible) of every candidate: 1 marker, 0 texture, -1 neither.

    ``eligible`` marks the candidates every test of the decision but the score passes.
    ``excluded``: (H, W) bool, an area whose candidates are neither (a board's).
    """
    features = decision.score_features(verdicts.evidence, min_radius_px)
    if len(truth):
        distance, _ = cKDTree(truth).query(verdicts.xy)
    else:
        distance = np.full(len(verdicts.xy), np.inf)
    label = np.where(distance <= MATCH_PX, 1, np.where(distance > CLEAR_PX, 0, -1))
    if excluded is not None:
        col, row = np.round(verdicts.xy).astype(np.intp).T
        inside = excluded[
            np.clip(row, 0, excluded.shape[0] - 1), np.clip(col, 0, excluded.shape[1] - 1)
        ]
        label[inside] = -1
    reason = verdicts.decision.reason
    eligible = (reason < 0) | (reason == decision.REASONS.index("score"))
    return features, label, eligible


def fit_logistic(features: np.ndarray, label: np.ndarray) -> tuple[np.ndarray, float]:
    """Logistic weights and bias, the two classes weighing equally."""
    mean, std = features.mean(axis=0), features.std(axis=0) + 1e-12
    z = (features - mean) / std
    weight = np.where(label > 0, 0.5 / max((label > 0).sum(), 1), 0.5 / max((label == 0).sum(), 1))

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        logit = z @ w[1:] + w[0]
        p = 1.0 / (1.0 + np.exp(-np.clip(logit, -50, 50)))
        value = np.sum(
            weight * (np.logaddexp(0.0, -logit) * label + np.logaddexp(0.0, logit) * (1 - label))
        )
        residual = weight * (p - label)
        grad = np.concatenate([[residual.sum()], z.T @ residual])
        value += _L2 * np.sum(w[1:] ** 2)
        grad[1:] += 2.0 * _L2 * w[1:]
        return float(value), grad

    w = minimize(loss, np.zeros(features.shape[1] + 1), jac=True, method="L-BFGS-B").x
    coefficients = w[1:] / std
    return coefficients, float(w[0] - np.sum(w[1:] * mean / std))


#: The kinds of real ground :func:`_real_ground` reads ...
AERIAL_GROUND, BOARD_BACKGROUNDS = "real aerial frames", "real boards' backgrounds"
#: ... and the folder of the data each is read from.
_REAL_GROUND_FOLDERS = {AERIAL_GROUND: "aerial_negatives", BOARD_BACKGROUNDS: "validationboof"}


def _real_ground(
    root: Path, quick: bool
) -> dict[str, tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], float]]:
    """Each kind of real ground without markers: its candidates (:func:`collect`) and megapixels."""
    aerial: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    aerial_mp = 0.0
    for frame in real_data.iter_aerial_negatives(root, 1 if quick else None):
        aerial_mp += frame.image.size / 1e6
        verdicts = _verdicts(frame.image, CALIBRATION_RADIUS_PX)
        aerial.append(collect(verdicts, CALIBRATION_RADIUS_PX[0], np.zeros((0, 2))))
    backgrounds: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    backgrounds_mp = 0.0
    for board in real_data.iter_validationboof(root, 1 if quick else None):
        area = np.any([real_data.board_mask(board.image.shape, g) for g in board.boards], axis=0)
        backgrounds_mp += (~area).sum() / 1e6
        verdicts = _verdicts(board.image, CALIBRATION_RADIUS_PX)
        backgrounds.append(collect(verdicts, CALIBRATION_RADIUS_PX[0], np.zeros((0, 2)), area))
    return {
        AERIAL_GROUND: (aerial, aerial_mp),
        BOARD_BACKGROUNDS: (backgrounds, backgrounds_mp),
    }


def run(quick: bool, root: Path | None, report: Report) -> dict[str, Any]:
    """Collect, fit, tabulate; report the constants. Returns the figures."""
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for image, radius_range, truth in _rendered(quick):
        parts.append(collect(_verdicts(image, radius_range), radius_range[0], truth))
    grounds = _real_ground(root, quick) if root is not None else {}
    if root is None:
        # Weights fitted without it are not the package's, and there is no tail to fit.
        report(real_data.absent("Real ground without markers (the false-alarm tail)"))
    for ground, folder in _REAL_GROUND_FOLDERS.items():
        if root is not None and not grounds[ground][0]:
            report(real_data.absent(f"Real ground without markers: {ground}", folder))
    grounds = {ground: read for ground, read in grounds.items() if read[0]}
    negatives = [p for kind, _ in grounds.values() for p in kind]
    features = np.concatenate([p[0] for p in parts + negatives])
    label = np.concatenate([p[1] for p in parts + negatives])
    eligible = np.concatenate([p[2] for p in parts + negatives])
    train = eligible & (label >= 0)
    coefficients, bias = fit_logistic(features[train], label[train])
    report(
        f"markers {int((label[train] == 1).sum())}, texture {int((label[train] == 0).sum())} "
        f"(of which real ground {sum(int((p[2] & (p[1] == 0)).sum()) for p in negatives)})"
    )
    report(
        "SCORE_WEIGHTS = (" + ", ".join(f"{c:.3f}" for c in coefficients) + ")\n"
        f"SCORE_BIAS = {bias:.3f}"
    )
    tables: dict[str, list[tuple[float, float]]] = {}
    tails: dict[str, tuple[float, float, float]] = {}
    default_rate = DetectorConfig().false_points_per_mp
    for name, (kind, megapixels) in grounds.items():
        # The tail of the score the package uses now: refitted weights change the
        # score, and their tail is measured after they are pasted in.
        weights = np.asarray(decision.SCORE_WEIGHTS)
        scores = np.concatenate(
            [p[0][p[2] & (p[1] == 0)] @ weights + decision.SCORE_BIAS for p in kind]
        )
        table = tables[name] = []
        for threshold in _SCORE_GRID:
            count = int((scores >= threshold).sum())
            if count == 0:
                break
            table.append((float(threshold), count / megapixels))
        report(
            f"{name}, {megapixels:.1f} MP, radius {CALIBRATION_RADIUS_PX[0]:g}-"
            f"{CALIBRATION_RADIUS_PX[1]:g} px: false points per megapixel at or above each "
            "score: " + ", ".join(f"{t:.1f}: {r:.3g}" for t, r in table)
        )
        if len(scores) > TAIL_POINTS:
            tail = tails[name] = exponential_tail(scores, megapixels)
            at_default = decision.threshold_for_rate(default_rate, tail)
            report(
                "  tail ({:.3f}, {:.4f}, {:.3f})".format(*tail)
                + f": threshold at {default_rate:g} / MP {at_default:.2f}"
            )
    chosen: tuple[float, float, float] | None = None
    if tails:
        # The stated rate must hold on every kind of ground: the strictest tail sets it.
        name = max(tails, key=lambda k: decision.threshold_for_rate(default_rate, tails[k]))
        chosen = tails[name]
        report(f"FALSE_ALARM_TAIL = ({chosen[0]:.3f}, {chosen[1]:.4f}, {chosen[2]:.3f})  # {name}")
    marker_scores = features[train & (label == 1)] @ coefficients + bias
    report(
        "markers' scores, quantiles 2 / 10 / 50 %: "
        + " / ".join(f"{q:.2f}" for q in np.quantile(marker_scores, [0.02, 0.1, 0.5]))
    )
    return {
        "weights": coefficients.tolist(),
        "bias": bias,
        "false_alarms": tables,
        "tails": tails,
        "tail": chosen,
    }


def exponential_tail(scores: np.ndarray, megapixels: float) -> tuple[float, float, float]:
    """(score s0, false points per MP at or above it, scale beta) of the texture's tail.

    Above s0 the rate falls as exp(-(s - s0) / beta): the excesses of the
    :data:`TAIL_POINTS` highest scores over the next one, whose mean is beta's
    maximum-likelihood estimate.
    """
    ranked = np.sort(scores)[::-1]
    threshold = float(ranked[TAIL_POINTS])
    scale = float(np.mean(ranked[:TAIL_POINTS] - threshold))
    return threshold, TAIL_POINTS / megapixels, scale


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = argparse.ArgumentParser(
        allow_abbrev=False,
        prog="marker-localizer bench calibrate",
        description="The decision's score weights and false-alarm rate, from data.",
    )
    parser.add_argument("--quick", action="store_true", help="one frame per set")
    add_json_option(parser)
    args = parser.parse_args(argv)
    run_report: Callable[[Report], dict[str, Any]] = lambda report: run(  # noqa: E731
        args.quick, real_data.data_root(), report
    )
    return run_and_save("calibration", run_report, args.json)
