"""The real-ground speed table: its grounds, its worker's figures, its table and targets."""

import cv2
import numpy as np
import pytest

from marker_localizer.bench import ground, real_data, speed


def _x_frame(size=96):
    image = np.full((size, size), 200, np.uint8)
    image[: size // 2, : size // 2] = image[size // 2 :, size // 2 :] = 30
    return cv2.GaussianBlur(image, (0, 0), 1.0)


def test_the_worst_cases_are_sensor_noise_and_a_tiling_of_xs():
    noise = ground.sensor_noise_frame(0, (200, 300))
    assert noise.shape == (200, 300) and noise.dtype == np.uint8
    assert noise.std() == pytest.approx(ground.NOISE_SIGMA_DN, rel=0.1)
    tiling = ground.x_tiling_frame(0, (64, 64))
    square = ground.TILING_SQUARE_PX
    # Neighbouring squares are dark and bright, squares two apart alike.
    centre = square // 2
    assert tiling[centre, centre] < 100 < tiling[centre, centre + square]
    assert abs(int(tiling[centre, centre]) - int(tiling[centre, centre + 2 * square])) < 15


def test_without_shared_data_the_real_grounds_are_skipped_with_a_line(monkeypatch):
    monkeypatch.setattr(ground, "flight_frames", lambda seed: [_x_frame()])
    lines = []
    found = ground.grounds(None, 0, lines.append)
    assert [g.name for g in found] == ["flight simulator", "sensor noise 40 DN", "X tiling 8 px"]
    assert [g.worst_case for g in found] == [False, True, True]
    assert lines[0].startswith("Real ground (only the simulated and worst-case grounds timed): ")
    assert lines[0].endswith("not found (set MARKER_LOCALIZER_DATA to the data folder), skipped.")


def test_the_real_data_folder_is_where_marker_localizer_data_says(monkeypatch, tmp_path):
    monkeypatch.setenv(real_data.DATA_ENV, str(tmp_path))
    assert real_data.data_root() == tmp_path
    monkeypatch.setenv(real_data.DATA_ENV, str(tmp_path / "missing"))
    assert real_data.data_root() is None
    assert str(tmp_path / "missing") in real_data.absent("Real images")


def test_every_subject_times_every_frame_of_every_ground_at_every_range_in_turn(tmp_path):
    found = [
        ground.Ground("x", [_x_frame(), _x_frame()]),
        ground.Ground("noise", [ground.sensor_noise_frame(1, (96, 96))]),
    ]
    path = tmp_path / "grounds.npz"
    ground.save_grounds(found, path)
    names = [speed.REFERENCE_SUBJECT, speed.HESSIAN_SUBJECT]
    ours, hessian = ground.run_subjects(names, path, [2, 1])
    assert ours.error == hessian.error == ""
    for result in (ours, hessian):
        assert [len(per_range) for per_range in result.timings] == [len(ground.RANGES)] * 2
        assert [len(t.times_ms) for t in result.timings[0]] == [2] * len(ground.RANGES)
        assert all(t.peak_mb > 0 for per_range in result.timings for t in per_range)
    assert ours.timings[0][0].points == [1, 1]  # the X, in both frames


def test_a_subject_whose_ground_worker_fails_is_reported_without_timings(tmp_path):
    path = tmp_path / "grounds.npz"
    ground.save_grounds([ground.Ground("x", [_x_frame()])], path)
    ours, unknown = ground.run_subjects([speed.REFERENCE_SUBJECT, "no such detector"], path, [1])
    assert unknown.error.startswith("worker failed: ") and unknown.timings == []
    assert ours.error == "" and len(ours.timings[0][0].times_ms) == 1


def _timings(ms, points=1, peak_mb=100.0):
    return [[ground.GroundTiming(list(ms), [points] * len(ms), peak_mb) for _ in ground.RANGES]]


def test_the_table_gives_each_grounds_median_and_worst_and_ours_over_the_peer():
    found = [ground.Ground("cirn_uas", [np.zeros((2160, 3840), np.uint8)] * 3)]
    results = [
        ground.SubjectTimings(speed.REFERENCE_SUBJECT, _timings([100, 140, 300])),
        # Frame by frame ours over the peer: 0.25, 0.2, 0.6 (the medians' ratio is 0.28).
        ground.SubjectTimings("peer", _timings([400, 700, 500], points=40)),
    ]
    table = ground.ground_table(found, results)
    row = next(line for line in table.splitlines() if line.startswith("cirn_uas 3840x2160"))
    assert row.split()[2:] == ["3", "3-30", "140", "300", "100", "1.0", "500", "40.0", "0.25"]
    verdict = ground.verdict(found, results)
    assert "median 140 ms (target <= 150: met), slowest 300 ms (target <= 400: met)" in verdict


def test_the_bound_is_judged_on_every_12_mp_frame_by_its_slowest_time_and_memory():
    found = [ground.Ground("sensor noise", [np.zeros((3000, 4096), np.uint8)], worst_case=True)]
    results = [ground.SubjectTimings(speed.REFERENCE_SUBJECT, _timings([900, 1200], peak_mb=300))]
    assert ground.verdict(found, results) == (
        "every 12 MP frame, both ranges: slowest 1200 ms (target <= 1000: missed), "
        "peak memory growth 300 MiB (target <= 500: met)"
    )
