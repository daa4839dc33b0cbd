"""bench speed and its workers: helpers, the rounds the subjects are timed in, the paired ratio."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import SMALL_SCENE

from marker_localizer.bench import speed, workers
from marker_localizer.synthetic import render_scene

# --------------------------------------------------------------------------- helpers


def test_peak_growth_sees_a_large_temporary_allocation():
    grown = speed.peak_growth_mb(lambda: np.ones(64 * 1024 * 1024 // 8).sum())
    assert grown > 40.0


def test_stage_medians_keep_the_pipeline_order():
    medians = speed.stage_medians([{"a": 1.0, "b": 5.0}, {"a": 3.0, "b": 7.0}])
    assert list(medians) == ["a", "b"]
    assert medians["a"] == pytest.approx(2.0)


def test_speed_worker_env_limits_every_thread_pool_to_one():
    env = workers.single_thread_env()
    assert env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == "1"


def test_tracking_views_keep_their_size_and_pan_by_the_step():
    base = np.arange(200 * 300, dtype=np.int64).reshape(200, 300)
    first, second = speed.tracking_view(base, 0), speed.tracking_view(base, 1)
    assert first.shape == second.shape
    dx, dy = speed.TRACKING_STEP_PX
    np.testing.assert_array_equal(second[:-dy, :-dx], first[dy:, dx:])


# --------------------------------------------------------------------------- rounds


def test_the_ratio_to_a_peer_is_the_median_of_the_paired_ratios():
    # A host slowed down in the second pair slows both subjects: the pairs keep 0.5.
    assert workers.paired_ratio([100.0, 300.0, 120.0], [200.0, 600.0, 240.0]) == pytest.approx(0.5)
    assert workers.paired_ratio([100.0, 300.0], [200.0, 300.0]) == pytest.approx(0.75)


def test_the_ratio_frame_by_frame_is_the_median_over_the_rounds_of_each_frames_pairs():
    # Two rounds of three frames, round by round: the third frame's ground is slow for
    # ours only.
    ours = [50.0, 60.0, 200.0, 55.0, 66.0, 210.0]
    peer = [100.0, 100.0, 200.0, 100.0, 120.0, 200.0]
    assert workers.paired_ratios_by_frame(ours, peer, 3) == pytest.approx([0.525, 0.575, 1.025])
    assert np.isnan(workers.paired_ratios_by_frame(ours[:5], peer[:5], 3)).all()


def test_the_ratio_without_the_kernels_time_leaves_out_each_sides_page_faults():
    # The peer's second frame spent a third of its time in the kernel, ours none.
    ours = speed.WorkerResult(speed.REFERENCE_SUBJECT, [100.0, 120.0], [0.0, 0.0])
    peer = speed.WorkerResult(speed.HESSIAN_SUBJECT, [200.0, 360.0], [0.0, 120.0])
    assert workers.paired_ratio(ours.times_ms, peer.times_ms) == pytest.approx(5 / 12)
    line = speed.ratio_without_kernel([ours, peer])
    assert line.startswith("ours/Hessian with each side's kernel time left out: 0.50 ")
    assert speed.ratio_without_kernel([ours]) == ""


class _Answering:
    """What the turns ask of a worker: whether it still answers, and its answers."""

    def __init__(self, running: bool = True) -> None:
        self.running = running
        self.asked: list[str] = []

    def ask(self, request: str) -> dict[str, float]:
        self.asked.append(request)
        return {"ms": 1.0}


def test_subjects_slower_than_a_turn_are_timed_after_the_others():
    # Radon's 1.7 s between two of the Hessian's detections let a VM's balloon take back
    # the Hessian's freed pages: the slow subject goes last, the others keep their turns.
    nan = float("nan")
    assert workers.paced_groups([0.2, 1.7, 0.3, nan]) == [[0, 2, 3], [1]]
    assert workers.paced_groups([0.2, 0.3]) == [[0, 1]]
    assert workers.paced_groups([2.0]) == [[0]]


def test_each_groups_turns_rotate_frame_by_frame_over_its_running_workers():
    started = [_Answering(), _Answering(), _Answering(running=False), _Answering()]
    assert workers.in_turn(started, 0, [0, 2, 3]) == [0, 3]
    assert workers.in_turn(started, 1, [0, 2, 3]) == [3, 0]
    assert workers.in_turn(started, 1, [1]) == [1]
    assert workers.in_turn(started, 1) == [1, 3, 0]


def test_the_group_timed_first_takes_an_untimed_turn_after_the_slower_warm_ups():
    started = [_Answering(), _Answering(running=False), _Answering(), _Answering()]
    workers.settle(started, [0, 1, 2], "0")
    assert [w.asked for w in started] == [["0"], [], ["0"], []]


def test_only_the_group_timed_first_is_settled():
    started = [_Answering(), _Answering(), _Answering()]
    groups = workers.settled_groups(started, [0.2, 1.7, 0.3], "0")
    assert groups == [[0, 2], [1]]
    assert [w.asked for w in started] == [["0"], [], ["0"]]


def test_the_ratio_is_not_given_when_the_subjects_timed_different_detections():
    assert np.isnan(workers.paired_ratio([100.0, 300.0], [200.0]))
    assert np.isnan(workers.paired_ratio([], []))


def test_every_subject_times_every_frame_of_every_round_in_its_own_worker(tmp_path):
    frames = [render_scene(SMALL_SCENE, seed).image for seed in (1, 2)]
    path = tmp_path / "frames.npz"
    np.savez(path, frame00=frames[0], frame01=frames[1])
    names = [speed.REFERENCE_SUBJECT, speed.HESSIAN_SUBJECT]
    ours, hessian = speed.run_subjects(names, path, n_frames=2, repeats=2)
    assert (ours.name, hessian.name) == tuple(names)
    assert ours.error == hessian.error == ""
    assert len(ours.times_ms) == len(hessian.times_ms) == 4
    # The kernel's time in each detection (accounted in ticks: it may exceed a tiny
    # frame's wall time by one).
    assert len(ours.kernel_ms) == len(hessian.kernel_ms) == 4
    assert min(ours.kernel_ms + hessian.kernel_ms) >= 0.0
    assert len(ours.stages_ms) == 4 and "screening" in ours.stages_ms[0]
    assert hessian.stages_ms == []
    assert np.isfinite(ours.rss_growth_mb) and np.isfinite(hessian.rss_growth_mb)
    assert np.isfinite(workers.paired_ratio(ours.times_ms, hessian.times_ms))
    line = speed.ratio_by_frame([ours, hessian], 2)
    assert line.startswith("ours/Hessian frame by frame")
    assert len(line.split(": ")[1].split(" / ")) == 2 and "-" not in line.split(": ")[1]


def test_a_subject_whose_worker_fails_is_reported_and_the_others_still_run(tmp_path):
    path = tmp_path / "frames.npz"
    np.savez(path, frame00=render_scene(SMALL_SCENE, 1).image)
    ours, unknown = speed.run_subjects(
        [speed.REFERENCE_SUBJECT, "no such detector"], path, n_frames=1, repeats=2
    )
    assert unknown.error.startswith("worker failed: ")
    assert unknown.times_ms == []
    assert ours.error == "" and len(ours.times_ms) == 2


def test_a_worker_that_does_not_answer_in_time_is_stopped_and_reported(tmp_path, monkeypatch):
    path = tmp_path / "frames.npz"
    np.savez(path, frame00=render_scene(SMALL_SCENE, 1).image)
    # Far less than a worker takes to import the detector and warm up.
    monkeypatch.setattr(workers, "WORKER_TIMEOUT_S", 0.01)
    (ours,) = speed.run_subjects([speed.REFERENCE_SUBJECT], path, n_frames=1, repeats=1)
    assert ours.error == "worker failed: no answer within 0.01 s"
    assert ours.times_ms == []


def test_families_is_refused_as_the_speed_benchmark_always_times_the_same_frames(capsys):
    """Before, ``--families`` was taken and ignored: a run of other frames than asked for."""
    with pytest.raises(SystemExit) as exit_info:
        speed.parse_args(["--families", "a"])
    assert exit_info.value.code == 2
    assert "unrecognized arguments: --families a" in capsys.readouterr().err
