"""Fast subset of the accuracy benchmark (marker_localizer.bench.accuracy), peers and real data.

Small rendered frames only; the real-data part skips when ``../shared/data`` is
absent; the whole module runs in well under a minute.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scenes import SMALL_SCENE
from shared_data import SHARED_DATA, needs_shared_data

from marker_localizer import Detector, DetectorConfig, evaluation
from marker_localizer.bench import accuracy, dull, peers, real_data
from marker_localizer.core import screening, symmetry_path
from marker_localizer.core.result import positions
from marker_localizer.errors import ConfigError
from marker_localizer.synthetic import SceneConfig, render_checkerboard, render_scene
from marker_localizer.synthetic.crlb import X_SNR_BANDS


def exact_x(size: int = 64) -> np.ndarray:
    """A blurred checker X whose centre is exactly (size/2 - 0.5, size/2 - 0.5), uint8."""
    image = np.full((size, size), 200, np.uint8)
    half = size // 2
    image[:half, :half] = 40
    image[half:, half:] = 40
    return cv2.GaussianBlur(image, (0, 0), 1.2)


def small_family(frames: int = 2) -> accuracy.Family:
    return accuracy.Family(
        "t", "test", (8.0, 16.0), frames, 1, lambda seed: render_scene(SMALL_SCENE, seed)
    )


class FixedDetector:
    """A peer that returns given points, for testing the scoring."""

    def __init__(self, name: str, points: np.ndarray) -> None:
        self.name = name
        self.points = points

    def detect(self, image_u8: np.ndarray, radius_range: peers.RadiusRange) -> np.ndarray:
        return self.points


# --------------------------------------------------------------------------- peers


def test_cornersubpix_refines_a_start_1_px_off_onto_the_exact_centre():
    refined = peers.corner_subpix(exact_x(), np.array([[30.8, 32.1]]), 5)
    np.testing.assert_allclose(refined, [[31.5, 31.5]], atol=0.02)


def test_cornersubpix_returns_nan_for_starts_at_the_border():
    refined = peers.corner_subpix(exact_x(), np.array([[1.0, 1.0], [31.0, 31.0]]), 5)
    assert np.isnan(refined[0]).all()
    assert np.isfinite(refined[1]).all()


def test_hessian_saddle_peer_finds_the_exact_x_and_nothing_else():
    found = peers.HessianSaddleDetector().detect(exact_x(), (8.0, 20.0))
    np.testing.assert_allclose(found, [[31.5, 31.5]], atol=0.02)


@pytest.mark.skipif(not peers.chess_corners_available(), reason="chess-corners not installed")
@pytest.mark.parametrize("method", ["chess", "radon"])
def test_chess_corners_points_use_the_pixel_centre_convention(method):
    found = peers.ChessCornersDetector(method).detect(exact_x(), (8.0, 20.0))
    distance = evaluation.nearest_distances(np.array([[31.5, 31.5]]), found)
    assert distance[0] < 0.05


@pytest.mark.skipif(not peers.mrgingham_available(), reason="mrgingham not installed")
def test_mrgingham_points_use_the_pixel_centre_convention():
    scene = render_checkerboard((480, 640), (10, 10), 26.0, background="flat", seed=0)
    found = peers.Mrgingham(10).detect(scene.image, (10.0, 30.0))
    matching = evaluation.match_points(found, scene.centres)
    assert matching.n_matched == 100
    offset = found[matching.detection_index] - scene.centres[matching.truth_index]
    assert np.abs(offset.mean(axis=0)).max() < 0.05


def test_opencv_board_peer_finds_every_corner_of_a_rendered_board():
    scene = render_checkerboard((480, 640), (6, 5), 30.0, tilt_deg=20.0, seed=2)
    found = peers.OpenCVChessboard((6, 5)).detect(scene.image, (10.0, 30.0))
    assert evaluation.match_points(found, scene.centres).n_matched == 30


# --------------------------------------------------------------------------- rendered families


def test_subpix_starts_lie_within_one_pixel_and_repeat_with_the_seed():
    truth = np.zeros((500, 2))
    a = accuracy.subpix_starts(truth, np.random.default_rng(3))
    b = accuracy.subpix_starts(truth, np.random.default_rng(3))
    assert np.linalg.norm(a, axis=1).max() <= 1.0
    assert np.linalg.norm(a, axis=1).mean() == pytest.approx(0.5, abs=0.05)
    np.testing.assert_array_equal(a, b)


def test_every_issue_family_is_defined_with_its_true_radius_range():
    by_key: dict[str, list[accuracy.Family]] = {}
    for family in accuracy.families():
        by_key.setdefault(family.key, []).append(family)
    assert sorted(by_key) == ["a", "b", "c", "d", "e", "g"]
    assert by_key["b"][0].radius_range == (2.5, 5.0)
    assert by_key["g"][0].radius_range == (5.0, 30.0)
    # (d) at 1280x960, at 4096x3000, and in the independent renderer's light.
    assert [f.variant for f in by_key["d"]] == ["", "4096x3000", "strong light"]
    assert by_key["e"][0].board_pattern == (10, 10)


def test_a_rendered_chessboard_frame_has_one_hundred_corners_in_the_frame():
    scene = accuracy.render_board_frame(4)
    assert len(scene.markers) == 100
    assert scene.image.shape == (960, 1280)


def test_family_evaluation_scores_ours_and_cornersubpix_on_the_same_frames():
    detectors = [
        peers.OurDetector(accuracy.REFERENCE_ROW, {}),
        FixedDetector("nothing", np.empty((0, 2))),
    ]
    result = accuracy.evaluate_family(small_family(), 2, 0, detectors)
    rows = result.rows
    by_name = {r.name: r for r in rows}
    ours = by_name[accuracy.REFERENCE_ROW].tally
    assert ours.frames == 2
    assert ours.recall >= 0.75
    assert ours.stats.mean < 0.1
    assert by_name["nothing"].tally.recall == 0.0
    subpix = rows[2]
    assert subpix.refiner
    assert subpix.tally.n_truth == ours.n_truth


def test_resolution_table_gives_each_detectors_recall_per_bin_of_marker_resolution():
    detectors = [
        peers.OurDetector(accuracy.REFERENCE_ROW, {}),
        FixedDetector("nothing", np.empty((0, 2))),
    ]
    split = accuracy.resolution_split((2.0, 7.0))
    family = replace(small_family(), splits=(split,))
    result = accuracy.evaluate_family(family, 2, 0, detectors)
    ours = result.rows[0].tally
    # SMALL_SCENE: radii 8-16 px tilted at most 30 degrees, blur 0.8-1.0: resolution 6.9-20.
    assert len(result.split_class) == len(ours.found) == ours.n_truth
    assert (result.split_class[:, 0] == 2).all()
    recall = accuracy.split_recall(result, split.labels)
    assert recall.markers == [0, 0, ours.n_truth]
    table = accuracy.split_table("t", recall)
    lines = table.splitlines()
    assert "< 2 (0)" in lines[1] and f">= 7 ({ours.n_truth})" in lines[1]
    assert lines[3].split()[-1] == f"{100 * ours.recall:.1f}%"
    assert lines[4].split()[-1] == "0.0%"
    assert len(lines) == 5  # the cornerSubPix refiner has no row: it is given the truth


def test_family_table_prints_the_peer_to_ours_ratio():
    ours = accuracy.Row(accuracy.REFERENCE_ROW)
    ours.tally.add(evaluation.match_points(np.array([[0.02, 0.0]]), np.zeros((1, 2))))
    peer = accuracy.Row("peer")
    peer.tally.add(evaluation.match_points(np.array([[0.1, 0.0]]), np.zeros((1, 2))))
    table = accuracy.family_table("t", [ours, peer])
    assert "5.00" in table.splitlines()[-1]


def test_family_table_prints_the_bound_and_the_error_over_it():
    ours = accuracy.Row(accuracy.REFERENCE_ROW)
    ours.tally.add(
        evaluation.match_points(np.array([[0.03, 0.0], [5.0, 5.0]]), np.zeros((1, 2))),
        truth_crlb_px=np.array([0.01]),
    )
    line = accuracy.family_table("t", [ours]).splitlines()[-1].split()
    assert line[-4:-1] == ["0.0100", "3.00", "-"]
    assert ours.tally.fp_per_frame == 1.0


def test_uneven_light_family_renders_dull_quadrants_shadows_and_every_markers_bound():
    (family,) = [f for f in accuracy.families() if f.key == "g"]
    scene = family.render(0)
    assert len(scene.imaging.cast_shadows) >= 3
    assert np.isfinite(scene.crlb_px).all() and (scene.crlb_px < 0.2).all()


def test_uneven_light_family_classes_its_markers_by_dull_margin_and_shadow():
    (family,) = [f for f in accuracy.families() if f.key == "g"]
    scene = family.render(0)
    split = family.splits[0]
    classes = split.classify(scene)
    margin = np.array([m.dull_margin for m in scene.markers])
    # Every marker has a dull quadrant; each cast shadow is placed about one marker.
    assert (margin < 1.0).all()
    assert scene.shadow_crossed.sum() == len(scene.imaging.cast_shadows)
    low, high = accuracy.DULL_MARGIN_EDGES
    lit = ~scene.shadow_crossed
    assert (classes[lit & (margin < low)] == 0).all()
    assert (classes[lit & (margin >= high)] == 2).all()
    assert (classes[scene.shadow_crossed] >= 3).all()
    assert len(split.labels) == 6 and split.labels[3] == "< 0.2 shadow"


def test_the_snr_model_recovers_a_log_linear_law_and_leaves_out_markers_without_a_bound():
    bound = np.array([0.01, 0.02, 0.05, 0.03, math.nan, 0.04])
    radius = np.array([3.0, 5.0, 4.0, 10.0, 6.0, 2.5])
    snr = np.exp(0.3 - 0.9 * np.log(bound) + 0.7 * np.log(radius))
    model = accuracy.XSnrModel.fit(snr, bound, radius)
    assert model.coefficients == pytest.approx((0.3, -0.9, 0.7))
    assert model.residual_sd == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(model.predict(bound[:4], radius[:4]), snr[:4])


def test_a_families_snr_model_follows_its_markers_the_bound_inversely():
    (tiny,) = [f for f in accuracy.families() if f.key == "b"]
    model = accuracy.x_snr_model(tiny, 1)
    # Both follow the X's contrast over the noise: the SNR about as the bound's inverse,
    # within a fifth or so in the log (docs/accuracy-journal.md). On one frame's 24 markers the
    # radius's own share is not yet pinned down.
    assert -1.3 < model.coefficients[1] < -0.7
    assert model.residual_sd < 0.3


def test_every_rendered_marker_family_splits_recall_by_the_xs_signal_to_noise_ratio():
    marker_families = [f for f in accuracy.families() if f.scene is not None]
    assert all(accuracy.X_SNR_SPLIT in f.splits for f in marker_families)
    (tiny,) = [f for f in marker_families if f.key == "b"]
    scene = tiny.render(0)
    lower, upper = (0.0, *X_SNR_BANDS), (*X_SNR_BANDS, math.inf)
    for band, truth in zip(accuracy.X_SNR_SPLIT.classify(scene), scene.markers, strict=True):
        assert lower[band] <= truth.x_snr < upper[band]
    # Rendered without its bounds, a marker has no SNR and no class.
    assert tiny.scene is not None
    assert (accuracy.X_SNR_SPLIT.classify(render_scene(tiny.scene, 0)) == -1).all()


def test_a_marker_missed_on_flat_ground_is_counted_as_lost_at_the_screening():
    frame = render_scene(SMALL_SCENE, 5)
    # A truth point where the frame holds no marker: nothing is screened there.
    flat = np.full_like(frame.image, 128)
    labelled = accuracy.LabelledFrame(
        flat,
        np.array([[240.0, 180.0]]),
        np.array([np.nan]),
        (8.0, 16.0),
        np.array([-1]),
        np.full((1, 2), np.nan),
    )
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    (row, _) = accuracy.evaluate_frames([labelled], 0, [ours]).rows
    assert row.lost_at == {"screening": 1}
    table = accuracy.losses_table([("flat", row)])
    assert "screening" in table and "prescreen" not in table


def test_markers_and_false_points_are_put_down_to_the_reading_that_added_them():
    scene = render_scene(SMALL_SCENE, 5)
    found = accuracy.LabelledFrame.rendered(scene, (8.0, 16.0))
    # The same frame with its truth 40 px away: every detection is a false point.
    moved = replace(found, truth=scene.centres + 40.0)
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    (row, _) = accuracy.evaluate_frames([found, moved], 0, [ours]).rows
    tally = row.tally
    assert tally.n_matched > 0 and tally.n_false_positives >= tally.n_matched
    assert row.found_by.total() == tally.n_matched
    assert row.false_by.total() == tally.n_false_positives
    assert set(row.found_by) | set(row.false_by) <= set(symmetry_path.READINGS.values())
    table = accuracy.readings_table([("small", row)], "Rendered frames")
    first_pass = f"{row.found_by['first pass']} / {row.false_by['first pass']}"
    assert "first pass" in table.splitlines()[1] and first_pass in table.splitlines()[-1]
    assert accuracy.row_record(row)["found_by"] == dict(row.found_by)


def test_the_reference_row_counts_the_markers_only_a_wider_radius_range_finds():
    """Issue 12, item 5, in the benchmark: each frame read again at a range a quarter
    wider either way. (d)'s seeds 106 and 107 at 4-40 px against 3.2-50, where the
    pipeline's tests expect item 5 to fail."""
    family = next(f for f in accuracy.families() if f.key == "d" and not f.variant)
    scenes = [family.render(seed) for seed in (106, 107)]
    frames = [accuracy.LabelledFrame.rendered(s, family.radius_range) for s in scenes]
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    (row, _) = accuracy.evaluate_frames(frames, 0, [ours]).rows
    assert accuracy.wider_range(family.radius_range) == pytest.approx((3.2, 50.0))
    only_wider = only_own = false_wider = 0
    for scene in scenes:
        (own, _), (wider, false) = (
            _found(
                Detector(DetectorConfig(marker_radius_min_px=low, marker_radius_max_px=high)), scene
            )
            for low, high in (family.radius_range, (3.2, 50.0))
        )
        only_wider, only_own = only_wider + len(wider - own), only_own + len(own - wider)
        false_wider += false
    assert row.range_checked
    assert (row.found_only_wider, row.found_only_own, row.false_wider) == (
        only_wider,
        only_own,
        false_wider,
    )
    table = accuracy.wider_range_table([("(d)", row)], "Rendered frames").splitlines()
    counts = [only_wider, only_own, row.tally.n_false_positives, false_wider]
    assert table[-1].split()[-4:] == [str(n) for n in counts]
    record = accuracy.row_record(row)
    keys = ("found_only_wider_range", "found_only_own_range", "false_points_wider_range")
    assert [record[k] for k in keys] == [only_wider, only_own, false_wider]


def test_peers_and_our_other_variants_are_not_read_at_a_wider_range():
    frame = accuracy.LabelledFrame.rendered(render_scene(SMALL_SCENE, 5), (8.0, 16.0))
    detectors = [
        peers.OurDetector("ours (ncc, paper)", {"refinement": "ncc"}),
        *peers.point_detectors()[:1],
    ]
    rows = accuracy.evaluate_frames([frame], 0, detectors).rows
    assert not any(row.range_checked for row in rows)
    assert all("found_only_wider_range" not in accuracy.row_record(row) for row in rows)


def _found(detector: Detector, scene) -> tuple[set[int], int]:
    """Indices of the scene's markers with a detection within 2 px, and the false points."""
    points = positions(detector.detect(scene.image))
    matching = evaluation.match_points(points, scene.centres)
    return set(matching.truth_index.tolist()), matching.n_false_positives


def test_main_prints_the_uneven_light_family_its_bound_and_the_summary(tmp_path, capsys):
    out = tmp_path / "accuracy.json"
    assert (
        accuracy.main(["--families", "g", "--frames", "1", "--no-curvature", "--json", str(out)])
        == 0
    )
    printed = capsys.readouterr().out
    assert "Family (g) uneven light" in printed
    assert "err/CRLB" in printed and "Summary, ours (symmetry)" in printed
    assert "Markers ours (symmetry) missed, by the test" in printed
    assert "by the reading that added them" in printed
    assert "times wider either way" in printed
    assert "Family (g) recall by the dull quadrant's lead over the dark paint" in printed
    assert f"Family (g) {accuracy.X_SNR_SPLIT.title}" in printed
    saved = json.loads(out.read_text())
    (title,) = [t for t in saved["synthetic"] if t.startswith("(g)") and ": recall" not in t]
    ours = saved["synthetic"][title][accuracy.REFERENCE_ROW]
    assert ours["crlb_mean_px"] > 0
    # The rendered truth has line directions: the reported ones are a few degrees off.
    assert 0.0 < ours["median_line_error_deg"] < 5.0
    split = saved["synthetic"][f"{title}: {accuracy.UNEVEN_LIGHT_SPLIT.title}"]
    assert set(split[accuracy.REFERENCE_ROW]) == set(accuracy.UNEVEN_LIGHT_SPLIT.labels)
    by_snr = saved["synthetic"][f"{title}: {accuracy.X_SNR_SPLIT.title}"]
    assert set(by_snr[accuracy.REFERENCE_ROW]) == set(accuracy.X_SNR_SPLIT.labels)
    assert set(saved["summary"]) == {"rendered (g)"}
    # Recall and false points carry their intervals, printed and saved.
    summary = saved["summary"]["rendered (g)"]
    found, truth, frames = summary["found"], summary["truth"], summary["frames"]
    # One frame says nothing of the spread between frames: the intervals are the plain ones.
    assert summary["recall_design_effect"] == summary["fp_dispersion"] == 1.0
    assert summary["recall_interval"] == pytest.approx(evaluation.recall_interval(found, truth))
    low, high = summary["fp_per_frame_interval"]
    assert low <= summary["fp_per_frame"] < high
    assert f"{low:.2f}-{high:.2f}" in printed.split("Summary, ours (symmetry)")[1]
    assert frames == 1


def test_held_out_frames_are_other_seeds_of_the_chosen_families_read_by_ours_alone(
    tmp_path, capsys
):
    out = tmp_path / "accuracy.json"
    status = accuracy.main(
        ["--families", "a,heldout", "--frames", "1", "--no-curvature", "--json", str(out)]
    )
    assert status == 0
    printed = capsys.readouterr().out
    first = accuracy.HELDOUT_SEED_OFFSET
    assert f"Held-out frames, ours (symmetry) alone: 1 frames a family of seeds {first}-" in (
        printed
    )
    saved = json.loads(out.read_text())
    assert set(saved["heldout"]) == {"rendered (a)"}
    held_out, timed = saved["heldout"]["rendered (a)"], saved["summary"]["rendered (a)"]
    assert held_out["frames"] == timed["frames"] == 1
    assert held_out["truth"] == 12
    # Another seed, another frame: the same family's figures, not the same ones.
    assert (held_out["mean_px"], held_out["fp_per_frame"]) != (
        timed["mean_px"],
        timed["fp_per_frame"],
    )


def test_held_out_frames_of_d_include_its_12_mp_and_strong_light_variants():
    options = accuracy.Options(frames=1, families=("d", "heldout"), curvature=False)
    printed: list[str] = []
    held_out = accuracy.run_heldout(options, printed.append)
    assert set(held_out) == {
        "rendered (d)",
        "rendered (d) 4096x3000",
        "rendered (d) strong light",
    }
    assert held_out["rendered (d) 4096x3000"]["truth"] == 24
    assert "rendered (d) 4096x3000" in printed[0]


def test_negatives_count_every_detection_per_frame_and_per_megapixel():
    frames = [real_data.UasFrame(str(i), np.zeros((1000, 500), np.uint8)) for i in range(2)]
    (row,) = accuracy.evaluate_negatives(
        frames, [FixedDetector("fixed", np.ones((3, 2)))], (3.0, 30.0)
    )
    assert row.extra["fp_per_frame"] == 3.0
    assert row.extra["fp_per_megapixel"] == pytest.approx(6.0)
    # Six false points in two frames, three on each: the exact Poisson interval of 3
    # a frame (counts that agree show no spread beyond Poisson's), read with Student's
    # t on the two frames' one degree of freedom.
    interval = (row.extra["fp_per_frame_low"], row.extra["fp_per_frame_high"])
    assert interval == evaluation.rate_interval(6, 2, frames=2)
    table = accuracy.negatives_table("t", [row])
    assert "FP/MP" in table and f"{interval[0]:.2f}-{interval[1]:.2f}" in table


def test_our_points_on_negatives_are_listed_by_the_reading_that_added_them():
    # A frame with markers read as one without: every detection counts as false.
    scene = render_scene(SMALL_SCENE, 5)
    frames = [real_data.UasFrame("markers", scene.image)]
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    (row,) = accuracy.evaluate_negatives(frames, [ours], (8.0, 16.0))
    assert row.false_by.total() == row.extra["fp_per_frame"] > 0
    table = accuracy.negatives_table("t", [row])
    assert "by reading" in table and f"first pass {row.false_by['first pass']}" in table


class _OneFrameOfTexture:
    """A peer that returns ``count`` points on the frame whose top-left pixel is 1."""

    name = "texture"

    def __init__(self, count: int) -> None:
        self.count = count

    def detect(self, image_u8: np.ndarray, radius_range: peers.RadiusRange) -> np.ndarray:
        return np.ones((self.count if image_u8[0, 0] else 0, 2))


def test_false_points_gathered_on_one_negative_frame_widen_their_interval():
    frames = [real_data.UasFrame(str(i), np.full((100, 100), i == 2, np.uint8)) for i in range(3)]
    (row,) = accuracy.evaluate_negatives(frames, [_OneFrameOfTexture(6)], (3.0, 30.0))
    assert row.extra["fp_per_frame"] == 2.0
    # 0, 0 and 6: variance 12 over a mean of 2, six times Poisson's spread.
    interval = (row.extra["fp_per_frame_low"], row.extra["fp_per_frame_high"])
    assert interval == pytest.approx(evaluation.rate_interval(6, 3, dispersion=6.0, frames=3))
    assert interval[1] > evaluation.rate_interval(6, 3, frames=3)[1]


def test_the_disc_lattice_is_ground_alone_between_its_two_levels_with_a_lattice_of_saddles():
    frame = accuracy.disc_lattice_frame(0)
    assert frame.image.shape == (960, 1280) and frame.image.dtype == np.uint8
    dark, bright = accuracy.DISC_LATTICE_LEVELS
    assert frame.image.min() < dark + 10 and frame.image.max() > bright - 10
    # Its discs make saddles everywhere: the Hessian peer finds hundreds in a frame.
    (hessian,) = [d for d in peers.point_detectors() if "Hessian" in d.name]
    assert len(hessian.detect(frame.image, accuracy.DISC_LATTICE_RADIUS_RANGE)) > 100


def test_a_stretched_disc_lattice_is_the_same_lattice_with_flat_discs():
    # The stretch has a stream of its own: the lattice and the noise stay, and the
    # discs' shading clips to the bright level.
    shaded, flat = (
        accuracy.disc_lattice_frame(3, scales=(0.3, 0.3), stretch=(gain, gain)).image.astype(float)
        for gain in (1.0, 1.6)
    )
    bright = accuracy.DISC_LATTICE_LEVELS[1]
    assert (flat >= bright - 5).mean() > 2 * (shaded >= bright - 5).mean()
    unclipped = flat < bright - 10
    assert np.corrcoef(shaded[unclipped], flat[unclipped])[0, 1] > 0.99


#: A scene that draws its ground as given: no marker, look-alike, light, blur or noise.
_BARE_GROUND = SceneConfig(
    width=160,
    height=120,
    n_markers=0,
    n_hard_negatives=0,
    blur_sigma_px=(0.0, 0.0),
    noise_sigma_dn=(0.0, 0.0),
    shot_noise_gain_dn=(0.0, 0.0),
    illumination_strength=0.0,
    n_shadows=0,
    gamma=(1.0, 1.0),
    peak_level=(1.0, 1.0),
)


def test_a_frame_on_real_ground_is_a_crop_of_its_real_frame_clear_of_its_targets():
    real = np.random.default_rng(0).uniform(20, 235, (400, 600)).astype(np.uint8)
    target = np.array([[300.0, 200.0]])
    margin = accuracy.REAL_GROUND_TARGET_CLEARANCE_PX
    for seed in range(6):
        frame = accuracy.real_ground_frame(_BARE_GROUND, [(real, target)], seed).image
        _, _, (left, top), _ = cv2.minMaxLoc(cv2.matchTemplate(real, frame, cv2.TM_SQDIFF))
        crop = real[top : top + frame.shape[0], left : left + frame.shape[1]]
        assert np.abs(frame.astype(int) - crop).max() <= 1
        x, y = target[0]
        assert not (
            left - margin < x < left + frame.shape[1] + margin
            and top - margin < y < top + frame.shape[0] + margin
        )


def test_a_real_frame_whose_every_crop_holds_a_target_is_a_config_error():
    real = np.full((200, 260), 100, np.uint8)
    with pytest.raises(ConfigError, match="clear"):
        accuracy.real_ground_frame(_BARE_GROUND, [(real, np.array([[130.0, 100.0]]))], 0)


def test_main_runs_one_family_and_saves_json(tmp_path, capsys):
    out = tmp_path / "accuracy.json"
    status = accuracy.main(
        ["--families", "e", "--frames", "1", "--no-curvature", "--json", str(out)]
    )
    assert status == 0
    printed = capsys.readouterr().out
    assert "Family (e)" in printed
    assert "cv2.cornerSubPix" in printed
    saved = json.loads(out.read_text())
    (table,) = saved["synthetic"].values()
    assert table[accuracy.REFERENCE_ROW]["recall"] == 1.0


def test_the_dull_grid_spreads_its_markers_over_the_frame_with_their_ground_inside_it():
    # Lined up along the frame's edge, a small X's ground leaves the frame and the
    # checks read it otherwise than about nearly every marker of a real frame.
    height, width = dull.FRAME_SHAPE
    for radius in dull.RADII_PX:
        scene = dull.dull_frame(radius, 0.7, seed=3)
        centres = scene.centres
        assert len(centres) == dull.MARKERS_PER_FRAME
        assert np.isfinite(screening.saddle_over_ground(scene.image, centres)).all()
        assert np.ptp(centres[:, 0]) > width / 2 and np.ptp(centres[:, 1]) > height / 2


def test_markers_with_a_dull_quadrant_are_read_at_each_range_with_even_paint_as_control():
    printed: list[str] = []
    figures = accuracy.run_dull(accuracy.Options(quick=True, families=("dull",)), printed.append)
    ranges = [peers.range_text(r) for r in dull.RANGES_PX]
    assert list(figures["found"]) == ranges
    assert figures["markers"] == {"8/1": dull.MARKERS_PER_FRAME, "8/0.7": dull.MARKERS_PER_FRAME}
    # Even paint, alone and clearly visible, is found at every range.
    assert [figures["found"][key]["8/1"] for key in ranges] == [dull.MARKERS_PER_FRAME] * 3
    (table,) = printed
    rows = {tuple(line.split()[:2]): line.split()[2:] for line in table.splitlines()[3:-1]}
    assert rows[("8", "0.7")] == [str(dull.MARKERS_PER_FRAME)] + [
        str(figures["found"][key]["8/0.7"]) for key in ranges
    ]
    assert table.splitlines()[-1].split()[-3:] == [str(figures["false"][key]) for key in ranges]


def test_family_a_on_real_ground_says_it_is_skipped_without_the_real_frames():
    printed: list[str] = []
    options = accuracy.Options(families=("ground",), data_root=None)
    assert accuracy.run_synthetic(options, printed.append, []) == {}
    assert printed == ["Family (a) on real ground: no real frame without markers found, skipped."]


def test_family_b_on_real_ground_says_it_is_skipped_without_the_real_frames():
    printed: list[str] = []
    options = accuracy.Options(families=("ground_b",), data_root=None)
    assert accuracy.run_synthetic(options, printed.append, []) == {}
    assert printed == ["Family (b) on real ground: no real frame without markers found, skipped."]


# --------------------------------------------------------------------------- real data


def test_uas_scoring_counts_both_targets_and_far_detections():
    frame = real_data.UasFrame("blank", np.zeros((8, 8), np.uint8))
    points = np.vstack([real_data.CIRN_TARGETS + 2.0, [[100.0, 100.0]]])
    (row,) = accuracy.evaluate_uas([frame], [FixedDetector("fixed", points)], (6.0, 24.0))
    assert row.extra["both_found"] == 1.0
    assert row.extra["fp_per_frame"] == 1.0


class _SmallXsFromThreePixels(FixedDetector):
    """Finds the targets, and a texture X more wherever its range reaches down to 3 px."""

    def detect(self, image_u8: np.ndarray, radius_range: peers.RadiusRange) -> np.ndarray:
        return self.points if radius_range[0] > 3.0 else np.vstack([self.points, [[9.0, 9.0]]])


def test_cirn_uas_is_read_at_its_targets_range_and_at_real_aerial_grounds():
    frame = real_data.UasFrame("blank", np.zeros((8, 8), np.uint8))
    detector = _SmallXsFromThreePixels("fixed", real_data.CIRN_TARGETS + 1.0)
    printed: list[str] = []
    results = accuracy.run_uas([frame], [detector], printed.append)
    assert list(results) == list(accuracy.CIRN_RANGES)
    assert (
        accuracy.CIRN_RANGES["cirn_uas_ground_range"].radius_range
        == accuracy.REAL_RADIUS_RANGES["aerial_negatives"]
    )
    assert results["cirn_uas"]["fixed"]["fp_per_frame"] == 0.0
    assert results["cirn_uas_ground_range"]["fixed"]["fp_per_frame"] == 1.0
    assert "radius range 6-24 px" in printed[0] and "radius range 3-30 px" in printed[1]


def test_board_scoring_counts_complete_boards_and_residuals():
    grid = np.stack(np.meshgrid(np.arange(4) * 20.0 + 50, np.arange(4) * 20.0 + 40), axis=-1)
    item = real_data.BoardImage(
        "set", "img", np.zeros((8, 8), np.uint8), [grid], grid.reshape(-1, 2)
    )
    full = FixedDetector("all", grid.reshape(-1, 2) + 0.05)
    partial = FixedDetector("some", grid.reshape(-1, 2)[:5])
    rows = accuracy.evaluate_boards([item], [full, partial], (5.0, 40.0))
    assert rows[0].extra["boards_complete"] == 1.0
    assert rows[0].extra["line_rms"] == pytest.approx(0.0, abs=1e-9)
    assert rows[0].extra["lens_rms"] == pytest.approx(0.0, abs=1e-6)
    assert rows[1].tally.recall == pytest.approx(5 / 16)
    assert rows[1].extra["boards_complete"] == 0.0
    # Only detectors with recall >= 50 % share the common-corner comparison.
    assert rows[0].extra["common_points"] == 2 * 16
    assert np.isnan(rows[1].extra["common_line_rms"])
    assert np.isnan(rows[1].extra["common_lens_rms"])
    assert rows[0].extra["common_lens_rms"] == pytest.approx(0.0, abs=1e-6)


def test_data_root_is_none_without_the_shared_folder(tmp_path):
    assert real_data.data_root(tmp_path / "repo") is None


@needs_shared_data
def test_validationboof_hand_clicks_agree_with_opencv_after_the_half_pixel_shift():
    item = next(real_data.iter_validationboof(SHARED_DATA, limit_per_folder=1))
    assert item.boards[0].shape == (6, 4, 2)
    matching = evaluation.match_points(item.opencv, item.reference)
    assert matching.n_matched == 24
    shifted = evaluation.match_points(item.opencv, item.reference + 0.5)
    # The shift removes a systematic +0.5 px bias, so the errors must be smaller with it.
    assert matching.errors_px.mean() < shifted.errors_px.mean()


@needs_shared_data
def test_opencvs_reference_boards_are_the_same_from_one_search_to_the_next():
    # Unseeded, OpenCV's sector-based search found one board or two in pycbd's flare
    # and none or one in its warped board, from one call to the next.
    for name in ("flare.jpg", "warped.jpg"):
        image = real_data.read_gray(SHARED_DATA / "pycbd" / name)
        first = real_data.opencv_boards(image)
        for _ in range(2):
            again = real_data.opencv_boards(image)
            assert len(again) == len(first), name
            assert all(np.array_equal(a, b) for a, b in zip(again, first, strict=True)), name


@needs_shared_data
def test_independent_frames_load_with_their_truth_bound_and_radius_range():
    frames = list(real_data.iter_independent(SHARED_DATA, limit_per_family=1))
    assert [f.family for f in frames] == list(accuracy.INDEPENDENT_FAMILIES)
    tiny = next(f for f in frames if f.family == "b")
    assert tiny.radius_range == (2.5, 5.0)
    assert tiny.truth.shape == (len(tiny.crlb_px), 2) and len(tiny.crlb_px) > 10
    assert (tiny.crlb_px > 0).all()
    assert tiny.radius_px.shape == tiny.crlb_px.shape
    assert ((tiny.radius_px >= 2.5) & (tiny.radius_px <= 5.0)).all()
    height, width = tiny.image.shape
    assert ((tiny.truth >= 0) & (tiny.truth < (width, height))).all()


@needs_shared_data
def test_family_a_on_real_ground_draws_its_markers_and_their_bounds_on_each_real_frame():
    family = accuracy.real_ground_family(SHARED_DATA)
    assert family is not None and family.radius_range == (6.0, 40.0)
    aerial = len(list(real_data.iter_aerial_negatives(SHARED_DATA)))
    scene = family.render(aerial)  # the first cirn_uas frame, away from its targets
    assert scene.image.shape == (960, 1280) and len(scene.markers) == 12
    assert np.isfinite(scene.crlb_px).all() and (scene.crlb_px > 0).all()


@needs_shared_data
def test_family_b_on_real_ground_draws_bs_tiny_markers_on_the_crop_of_as_real_ground():
    tiny = accuracy.real_ground_family(SHARED_DATA, "ground_b")
    assert tiny is not None and tiny.radius_range == (2.5, 5.0)
    assert "(ground_b) family (b)'s tiny markers" in tiny.title
    aerial = len(list(real_data.iter_aerial_negatives(SHARED_DATA)))
    scene = tiny.render(aerial)  # the first cirn_uas frame, away from its targets
    assert scene.image.shape == (960, 1280) and len(scene.markers) == 24
    assert all(2.5 <= m.radius_px <= 5.0 for m in scene.markers)
    assert np.isfinite(scene.crlb_px).all() and (scene.crlb_px > 0).all()
    # The same markers family (b) draws from that seed on the renderer's ground ...
    (b,) = (f for f in accuracy.families() if f.key == "b")
    assert np.array_equal(scene.centres, b.render(aerial).centres)
    # ... on the real crop family (a) on real ground draws from that seed: away from
    # every marker and look-alike, the two frames show the same ground under light,
    # gamma and noise of their own (the renderer's ground shares next to nothing).
    ground = accuracy.real_ground_family(SHARED_DATA)
    assert ground is not None
    other = ground.render(aerial)
    away = np.ones(scene.image.shape, bool)
    points = [(m.x, m.y) for m in (*scene.markers, *other.markers)]
    points += [(x, y) for _, x, y in (*scene.negatives, *other.negatives)]
    rows, cols = np.mgrid[: scene.image.shape[0], : scene.image.shape[1]]
    for x, y in points:
        away &= np.hypot(cols - x, rows - y) > 80
    assert away.mean() > 0.2
    share = np.corrcoef(scene.image[away].astype(float), other.image[away].astype(float))[0, 1]
    assert share > 0.7


@needs_shared_data
def test_families_ground_b_and_heldout_read_held_out_frames_of_family_b_on_real_ground_alone():
    options, _ = accuracy.parse_args(["--families", "ground_b,heldout", "--frames", "1"])
    figures = accuracy.run_heldout(replace(options, data_root=SHARED_DATA), [].append)
    (tiny,) = figures.values()
    assert list(figures) == ["rendered (ground_b)"]
    assert (tiny["frames"], tiny["truth"]) == (1, 24)


def test_real_ground_seen_from_half_the_height_spans_twice_the_pixels_with_its_levels():
    rng = np.random.default_rng(0)
    ground = cv2.GaussianBlur(rng.uniform(40, 200, (60, 80)).astype(np.float32), (0, 0), 2.0)
    frame = real_data.UasFrame("ground", ground.astype(np.uint8))
    (closer,) = accuracy.closer_frames([frame], seed=0)
    again = next(accuracy.closer_frames([frame], seed=0))
    assert closer.image.dtype == np.uint8 and closer.image.shape == (120, 160)
    assert np.array_equal(closer.image, again.image)
    shrunk = cv2.resize(closer.image.astype(np.float32), (80, 60), interpolation=cv2.INTER_AREA)
    assert np.abs(shrunk - frame.image).mean() < 1.5
    assert abs(closer.image.mean() - frame.image.mean()) < 0.5


def test_a_colour_frame_seen_from_half_the_height_keeps_its_colour_with_the_greys_noise():
    rng = np.random.default_rng(1)
    grey = cv2.GaussianBlur(rng.uniform(40, 200, (60, 80)).astype(np.float32), (0, 0), 2.0)
    colour = np.clip(grey[..., None] * [0.8, 1.0, 1.2], 0, 255).astype(np.uint8)
    frame = real_data.UasFrame("ground", cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), colour)
    (closer,) = accuracy.closer_frames([frame], seed=0)
    (plain,) = accuracy.closer_frames([real_data.UasFrame("ground", frame.image)], seed=0)
    assert np.array_equal(closer.image, plain.image) and plain.colour is None
    assert closer.colour.shape == (120, 160, 3) and closer.colour.dtype == np.uint8
    assert (
        np.abs(cv2.cvtColor(closer.colour, cv2.COLOR_BGR2GRAY) - closer.image.astype(int)).max()
        <= 2
    )


def test_a_data_folder_without_a_set_skips_that_set_with_a_line_naming_its_folder(
    tmp_path, monkeypatch
):
    # A folder missing validationboof/ was a FileNotFoundError traceback, and the
    # aerial frames' line named ../shared/data whatever the folder read.
    monkeypatch.setenv(real_data.DATA_ENV, str(tmp_path))
    printed: list[str] = []
    options = accuracy.Options(quick=True, data_root=tmp_path)
    assert accuracy.run_real(options, printed.append) == {}
    assert accuracy.run_negatives(options, printed.append) == {}
    assert accuracy.run_independent(options, printed.append, []) == {}
    folders = ["validationboof", "libcbdetect", "pycbd", "cirn_uas", "aerial_negatives"]
    for line, folder in zip(printed, [*folders, "independent"], strict=True):
        assert f"{tmp_path / folder} not found (set MARKER_LOCALIZER_DATA" in line


def test_held_out_frames_without_a_family_to_draw_them_from_say_so():
    printed: list[str] = []
    options = accuracy.Options(quick=True, families=("heldout",), curvature=False)
    assert accuracy.run_heldout(options, printed.append) == {}
    assert printed == [  # it printed nothing at all
        "Held-out frames: none, as none of the rendered families they are drawn from "
        "was chosen (--families a,heldout reads (a)'s)."
    ]


def test_the_closer_aerial_ground_is_skipped_without_the_real_frames():
    printed: list[str] = []
    assert accuracy.run_closer_negatives(accuracy.Options(data_root=None), printed.append) == {}
    assert printed == []


@needs_shared_data
def test_the_closer_aerial_ground_is_read_by_the_reference_row_alone():
    printed: list[str] = []
    options = accuracy.Options(quick=True, families=("negatives",), data_root=SHARED_DATA)
    figures = accuracy.run_closer_negatives(options, printed.append)
    assert list(figures) == [accuracy.REFERENCE_ROW]
    assert figures[accuracy.REFERENCE_ROW]["fp_per_frame"] >= 0
    assert "half the height" in printed[0]


@needs_shared_data
def test_each_rendered_family_draws_every_radius_the_independent_family_draws():
    rendered = {f.key: f.radius_range for f in accuracy.families() if not f.variant}
    for frame in real_data.iter_independent(SHARED_DATA):
        low, high = rendered[frame.family]
        assert low <= frame.radius_range[0] and frame.radius_range[1] <= high, frame.name


@needs_shared_data
def test_independent_table_scores_every_detector_against_the_frames_bound():
    frame = next(real_data.iter_independent(SHARED_DATA, 1, ("a",)))
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    rows = accuracy.evaluate_frames([accuracy.LabelledFrame.independent(frame)], 0, [ours]).rows
    tally = rows[0].tally
    found = np.asarray(tally.found, dtype=bool)
    assert tally.mean_crlb_px == pytest.approx(frame.crlb_px[found].mean())
    assert rows[1].refiner and rows[1].tally.n_truth == len(frame.truth)


@needs_shared_data
def test_independent_markers_are_classed_by_the_snr_their_bound_and_radius_give():
    frame = next(real_data.iter_independent(SHARED_DATA, 1, ("b",)))
    assert accuracy.LabelledFrame.independent(frame).split_class.shape == (len(frame.truth), 0)
    model = accuracy.XSnrModel((0.0, -1.0, 1.0), 0.1)  # SNR = radius / bound
    classes = accuracy.LabelledFrame.independent(frame, model).split_class
    expected = np.digitize(frame.radius_px / frame.crlb_px, X_SNR_BANDS)
    np.testing.assert_array_equal(classes[:, 0], expected)


@needs_shared_data
def test_the_given_radius_range_finds_as_many_independent_markers_as_a_wider_one():
    """Issue 12, item 5, on frames no step was tuned on (the independent renderer's).

    Each frame is read with the radius range its truth gives and with a wider one,
    the default 4-40 px. A few markers change hands between the two (their
    candidates and the caps differ), but the tighter, correct range finds as many
    in every family (a, c, d, g: 47, 31, 30, 23 of 48, 36, 36, 48 against 46, 31,
    30, 21).
    """
    wider = (4.0, 40.0)
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    found: dict[tuple[str, str], int] = {}
    for frame in real_data.iter_independent(SHARED_DATA, families=("a", "c", "d", "g")):
        assert wider[0] <= frame.radius_range[0] and frame.radius_range[1] <= wider[1]
        for reading, radius_range in (("given", frame.radius_range), ("wider", wider)):
            matched = evaluation.match_points(ours.detect(frame.image, radius_range), frame.truth)
            found[frame.family, reading] = found.get((frame.family, reading), 0) + matched.n_matched
    for family in ("a", "c", "d", "g"):
        assert found[family, "given"] >= found[family, "wider"], family


@needs_shared_data
def test_our_detector_finds_the_inner_corners_of_a_real_board():
    item = next(real_data.iter_validationboof(SHARED_DATA, limit_per_folder=1))
    ours = peers.OurDetector(accuracy.REFERENCE_ROW, {})
    found = ours.detect(item.image, accuracy.REAL_RADIUS_RANGES["validationboof"])
    assert evaluation.match_points(found, item.reference).n_matched >= 22
