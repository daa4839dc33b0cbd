"""Per-camera statistics and diagnostic levels, on a clock the tests drive."""

import dataclasses
import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from marker_localizer.ros.diagnostics import (
    ERROR,
    OK,
    WARN,
    WINDOW_MAX_FRAMES,
    CameraStats,
    DiagnosticThresholds,
    camera_level,
    camera_status,
    diagnostic_array,
    drop_report,
    frames_lost_upstream,
    node_status,
)

S = 1_000_000_000  # ns per s
LIMITS = DiagnosticThresholds(latency_warn_ms=200.0, input_timeout_s=2.0, window_s=10.0)


def healthy_camera(frames=10, period_s=0.5, latency_ms=50.0, markers=3, clock_offset_s=0.01):
    """A camera that sent ``frames`` frames at ``period_s``, each processed; the last one now."""
    stats = CameraStats("cam1", start_ns=0, window_s=LIMITS.window_s)
    for i in range(frames):
        t = int((i + 1) * period_s * S)
        stats.frame_received(t, stamp_ns=t)
        stats.frame_processed(
            t, latency_ms=latency_ms, clock_offset_s=clock_offset_s, markers=markers
        )
    return stats, int(frames * period_s * S)


def level_of(status):
    return status.level[0]


def values_of(status):
    return {kv.key: kv.value for kv in status.values}


def test_camera_with_steady_frames_is_ok_and_reports_rates():
    stats, now = healthy_camera()
    snap = stats.snapshot(now)
    assert camera_level(snap, LIMITS) == (OK, "ok")
    assert snap.input_rate_hz == pytest.approx(2.0)
    assert snap.processed_rate_hz == pytest.approx(2.0)
    assert snap.latency_p50_ms == pytest.approx(50.0)
    assert snap.markers_per_frame == pytest.approx(3.0)


def test_camera_warns_when_more_than_ten_percent_of_frames_are_dropped():
    stats, now = healthy_camera(frames=10)
    stats.frame_replaced(now)
    assert camera_level(stats.snapshot(now), LIMITS)[0] == OK  # 1 of 10: not more than 10 %
    stats.frame_too_old(now)
    level, message = camera_level(stats.snapshot(now), LIMITS)
    assert (level, message) == (WARN, "20 % of frames dropped")


def test_dropped_frames_leave_the_window_and_the_warning_clears():
    stats, now = healthy_camera(frames=10)
    stats.frame_replaced(now)
    stats.frame_replaced(now)
    assert camera_level(stats.snapshot(now), LIMITS) == (WARN, "20 % of frames dropped")
    later = now + 11 * S
    for i in range(4):
        t = later - (3 - i) * S // 2
        stats.frame_received(t, stamp_ns=t)
    assert camera_level(stats.snapshot(later), LIMITS)[0] == OK


def test_camera_warns_when_latency_p95_exceeds_the_limit():
    stats, now = healthy_camera(latency_ms=250.0)
    level, message = camera_level(stats.snapshot(now), LIMITS)
    assert level == WARN
    assert message == "latency p95 250 ms > 200 ms"


def test_camera_is_error_when_no_frame_arrives_within_the_timeout():
    stats, now = healthy_camera()
    level, message = camera_level(stats.snapshot(now + 3 * S), LIMITS)
    assert (level, message) == (ERROR, "no frame for 3.0 s")


def test_camera_that_never_sent_a_frame_is_error_after_the_timeout_only():
    stats = CameraStats("cam4", start_ns=5 * S, window_s=10.0)
    assert camera_level(stats.snapshot(6 * S), LIMITS)[0] == OK
    assert camera_level(stats.snapshot(8 * S), LIMITS) == (ERROR, "no frame since start, 3.0 s")


def test_a_camera_silent_while_a_sim_time_clock_stands_still_is_error_on_the_steady_clock():
    # use_sim_time without /clock (a bag not playing, or ended): the node's clock stays
    # at its last value however long no frame comes.
    clock = 7 * S
    stats = CameraStats("cam0", start_ns=clock, window_s=10.0, start_steady_ns=100 * S)
    assert camera_level(stats.snapshot(clock, 109 * S), LIMITS) == (
        ERROR,
        "no frame since start, 9.0 s",
    )
    stats.frame_received(clock, stamp_ns=clock, steady_ns=110 * S)
    assert camera_level(stats.snapshot(clock, 111 * S), LIMITS)[0] == OK
    assert camera_level(stats.snapshot(clock, 117 * S), LIMITS) == (ERROR, "no frame for 7.0 s")
    # Read on the clock alone (replay, on its bag's times), as before.
    replayed = CameraStats("cam0", start_ns=clock, window_s=10.0)
    assert camera_level(replayed.snapshot(clock, 117 * S), LIMITS)[0] == OK


def test_a_sim_time_clock_that_starts_at_a_bags_date_restarts_the_windows_from_there():
    # use_sim_time before the first /clock reads 0; the bag's clock then starts at its
    # recording's date, decades later.
    bag_start = 1_700_000_000 * S
    stats = CameraStats("cam0", start_ns=0, window_s=10.0)
    stats.frame_received(0, stamp_ns=bag_start)
    stats.frame_processed(bag_start + S // 10, 30.0, float("nan"), 1)
    snap = stats.snapshot(bag_start + S)
    assert snap.since_last_frame_s == 0.9 and snap.received == 1  # from the first /clock
    assert camera_level(snap, LIMITS)[0] == OK
    silent = CameraStats("cam1", start_ns=0, window_s=10.0)
    assert camera_level(silent.snapshot(bag_start), LIMITS)[0] == OK  # the start, not 1970
    assert camera_level(silent.snapshot(bag_start + 3 * S), LIMITS) == (
        ERROR,
        "no frame since start, 3.0 s",
    )


def test_failed_frame_keeps_the_camera_at_error_for_one_window():
    stats, now = healthy_camera()
    stats.frame_failed(now, "ImageError: unsupported encoding 'nv24'")
    level, message = camera_level(stats.snapshot(now + S // 2), LIMITS)
    assert level == ERROR
    assert "unsupported encoding 'nv24'" in message
    for i in range(25):  # frames keep coming, all good
        stats.frame_received(now + (i + 1) * S // 2, stamp_ns=now + (i + 1) * S // 2)
    assert camera_level(stats.snapshot(now + 12 * S), LIMITS)[0] == OK
    assert stats.snapshot(now + 12 * S).errors == 1


def test_frames_lost_upstream_are_counted_from_the_gaps_between_stamps():
    period_ns = S // 10
    rng = np.random.default_rng(4)
    sent = np.arange(1000) * period_ns + rng.normal(0, 0.05 * period_ns, 1000).astype(np.int64)
    arrived = sent + 30_000_000  # 30 ms on the way
    kept = np.sort(rng.choice(1000, 540, replace=False))  # 46 % lost, as measured on DDS
    lost, rate_hz = frames_lost_upstream(sent[kept], arrived[kept])
    assert lost == kept[-1] - kept[0] + 1 - len(kept)
    assert rate_hz == pytest.approx(10.0, rel=0.01)
    assert frames_lost_upstream(sent, arrived) == (0, pytest.approx(10.0, rel=0.01))
    assert frames_lost_upstream(sent[kept], arrived[kept], rate_hz=10.0)[0] == lost
    assert frames_lost_upstream(sent[:5], arrived[:5])[0] == 0  # too few gaps to know the rate
    assert frames_lost_upstream(sent[::-1], arrived)[0] == 0  # stamps going back count nothing


def test_stamps_that_jitter_by_a_fifth_of_a_period_read_no_loss_that_is_not_there():
    # A driver that stamps on arrival: 20 ms of jitter at 10 Hz, every frame received.
    # The 10th-percentile gap alone gave a period of 78 ms, and 29 % of frames lost.
    rng = np.random.default_rng(0)
    for loss in (0.0, 0.46):
        sent = np.arange(200) * (S // 10) + rng.normal(0, 0.02 * S, 200).astype(np.int64)
        kept = np.sort(rng.choice(np.arange(1, 199), int(198 * (1 - loss)), replace=False))
        stamps = np.sort(sent[np.r_[0, kept, 199]])
        lost, rate_hz = frames_lost_upstream(stamps, stamps + 30_000_000)
        assert rate_hz == pytest.approx(10.0, rel=0.02)
        assert abs(lost - (198 - len(kept))) <= 0.06 * 200


def test_frames_lost_in_a_queue_are_counted_though_the_rest_arrive_at_once():
    # The node stalled: what the queue kept arrives 1 ms apart, two frames lost in it.
    period_ns = S // 10
    sent = np.arange(30) * period_ns
    arrived = sent + 20_000_000
    arrived[20:] = arrived[20] + np.arange(10) * 1_000_000
    kept = np.delete(np.arange(30), [24, 25])
    assert frames_lost_upstream(sent[kept], arrived[kept])[0] == 2


@pytest.mark.parametrize(
    "glitch",
    ["an unset stamp (0)", "a stamp an hour ahead", "stamps 5 s back, then on again"],
)
def test_a_jump_of_the_stamps_clock_is_no_frame_lost(glitch):
    # Every frame of a 10 Hz camera arrives; only the stamps' clock misbehaves.
    sent = 1_700_000_000 * S + np.arange(30) * (S // 10)
    arrived = sent + 30_000_000
    stamps = sent.copy()
    if glitch == "an unset stamp (0)":
        stamps[15] = 0
    elif glitch == "a stamp an hour ahead":
        stamps[15] += 3600 * S
    else:
        stamps[10:20] -= 5 * S
    assert frames_lost_upstream(stamps, arrived) == (0, pytest.approx(10.0))
    assert frames_lost_upstream(stamps, arrived, rate_hz=10.0)[0] == 0


def lossy_camera(keep):
    """A 10 Hz camera of which the frames ``keep(k)`` arrive, stamped on another clock."""
    stats = CameraStats("cam2", start_ns=0, window_s=LIMITS.window_s)
    for k in range(100):
        if keep(k):
            stats.frame_received(k * S // 10, stamp_ns=k * S // 10 - 7 * S)
    return stats.snapshot(99 * S // 10)


def test_camera_warns_with_the_figure_when_frames_are_lost_before_the_node():
    rng = np.random.default_rng(5)
    arrived = lossy_camera(lambda k: k in (0, 99) or rng.random() > 0.46)
    lost = 100 - arrived.received_in_window
    status = camera_status("marker_localizer", arrived, LIMITS)
    assert level_of(status) == WARN
    assert status.message == (
        f"{lost} % of frames lost before the node ({lost} of 100 in 10 s, from stamp gaps at 10 Hz)"
    )
    assert values_of(status)["lost upstream in window"] == str(lost)


def test_a_regular_loss_needs_the_expected_rate_to_be_seen():
    every_other = lossy_camera(lambda k: k % 2 == 0 or k == 99)
    assert camera_level(every_other, LIMITS) == (OK, "ok")  # looks like a 5 Hz camera
    at_10_hz = dataclasses.replace(LIMITS, expected_rate_hz=10.0)
    assert camera_level(every_other, at_10_hz) == (
        WARN,
        "49 % of frames lost before the node (49 of 100 in 10 s, from stamp gaps at 10 Hz)",
    )


def test_a_long_error_text_is_kept_short_in_the_status():
    stats, now = healthy_camera()
    stats.frame_failed(now, "ImageError: " + "x" * 1_000_000)
    status = camera_status("marker_localizer", stats.snapshot(now), LIMITS)
    assert len(values_of(status)["last error"]) < 300
    assert len(status.message) < 400


def test_error_wins_over_warning_and_both_are_named():
    stats, now = healthy_camera(latency_ms=900.0)
    level, message = camera_level(stats.snapshot(now + 5 * S), LIMITS)
    assert (level, message) == (ERROR, "no frame for 5.0 s; latency p95 900 ms > 200 ms")
    stats.frame_received(now + 5 * S, stamp_ns=now + S // 2)  # the next frame, late
    stats.frame_failed(now + 5 * S, "RuntimeError: boom")
    level, message = camera_level(stats.snapshot(now + 5 * S), LIMITS)
    assert (level, message) == (
        ERROR,
        "frame failed 0.0 s ago: RuntimeError: boom; latency p95 900 ms > 200 ms",
    )


@pytest.mark.parametrize("clock_offset_s", [1.7e9, -3600.0])
def test_stamps_from_another_clock_show_as_the_clock_offset_and_change_no_level(clock_offset_s):
    # An old bag played without /clock (stamps 54 years behind), a stamp an hour ahead.
    stats, now = healthy_camera(clock_offset_s=clock_offset_s)
    status = camera_status("loc", stats.snapshot(now), LIMITS)
    assert (status.level, status.message) == (bytes([OK]), "ok")
    assert values_of(status)["clock offset p50 (s)"] == f"{clock_offset_s:.3f}"


def test_drop_report_names_each_reason_since_the_last_report():
    stats, now = healthy_camera()
    assert drop_report(stats.snapshot(now), (0, 0), 2.0) is None
    for _ in range(3):
        stats.frame_replaced(now)
    stats.frame_too_old(now)
    assert drop_report(stats.snapshot(now), (0, 0), 2.0) == (
        "cam1: 4 frame(s) dropped: 3 replaced in the mailbox by a newer frame (workers busy); "
        "1 waited longer than max_frame_age_s = 2 s"
    )
    assert drop_report(stats.snapshot(now), (3, 1), 2.0) is None


def test_snapshot_without_results_has_nan_statistics():
    snap = CameraStats("cam0", 0, 10.0).snapshot(S)
    assert math.isnan(snap.clock_offset_s)
    assert math.isnan(snap.latency_p95_ms)
    assert math.isnan(snap.markers_per_frame)
    assert not snap.any_frame


def test_camera_status_follows_diagnostic_updater_conventions():
    stats, now = healthy_camera()
    extra = {"camera_info": "640x480"}
    status = camera_status("marker_localizer", stats.snapshot(now), LIMITS, extra)
    assert status.name == "marker_localizer: cam1"
    assert status.hardware_id == "cam1"
    assert status.level == bytes([OK])
    values = values_of(status)
    assert values["frames received"] == "10"
    assert values["input rate (Hz)"] == "2.00"
    assert values["latency p95 (ms)"] == "50.0"
    assert values["dropped by mailbox"] == values["dropped by age"] == "0"
    assert values["camera_info"] == "640x480"
    assert all(isinstance(v, str) for v in values.values())


def test_node_status_reports_the_worst_camera_and_names_it():
    good, now = healthy_camera()
    bad = CameraStats("cam2", start_ns=0, window_s=10.0)
    statuses = [
        camera_status("loc", good.snapshot(now), LIMITS),
        camera_status("loc", bad.snapshot(now), LIMITS),
    ]
    status = node_status("loc", statuses, {"workers": "2"})
    assert status.name == "loc: node"
    assert status.level == bytes([ERROR])
    assert status.message == "cam2 ERROR: no frame since start, 5.0 s"
    assert values_of(status) == {"workers": "2"}
    healthy = node_status("loc", statuses[:1], {})
    assert (healthy.level, healthy.message) == (bytes([OK]), "all 1 cameras ok")


def test_diagnostic_array_carries_the_stamp_and_every_status():
    stats, now = healthy_camera()
    statuses = [camera_status("loc", stats.snapshot(now), LIMITS)]
    array = diagnostic_array(Time(sec=12, nanosec=5), statuses)
    assert array.header.stamp == Time(sec=12, nanosec=5)
    assert [s.name for s in array.status] == ["loc: cam1"]


def test_candidates_the_detectors_caps_cut_are_counted_and_shown_per_camera():
    stats, now = healthy_camera(frames=3)
    stats.frame_processed(now, latency_ms=50.0, clock_offset_s=0.01, markers=2, capped=1200)
    stats.frame_processed(now, latency_ms=50.0, clock_offset_s=0.01, markers=2, capped=30)
    snap = stats.snapshot(now)
    assert (snap.frames_capped, snap.candidates_capped) == (2, 1230)
    values = values_of(camera_status("marker_localizer", snap, LIMITS))
    assert values["frames capped"] == "2"
    assert values["candidates capped"] == "1230"


def test_16_bit_frames_all_under_a_16th_of_white_warn_with_the_bit_depth_they_fit():
    stats, now = healthy_camera(frames=2)  # 8-bit frames, no level reported
    for level in (3000.0, 4095.0):  # a 12-bit camera's words read at bit_depth 16
        stats.frame_processed(now, 50.0, 0.01, markers=1, peak=level, bit_depth=16)
    snap = stats.snapshot(now)
    assert snap.bit_depth_hint == 12
    assert snap.peak_share == pytest.approx(4095.0 / 65535.0)
    assert camera_level(snap, LIMITS) == (
        WARN,
        "16-bit frames under 1/16 of white: a 12-bit camera wants detector.bit_depth 12",
    )
    values = values_of(camera_status("loc", snap, LIMITS))
    assert values["peak level in window (% of white)"] == "6.2"
    # Told the depth, the same levels are bright enough: no warning.
    stats.frame_processed(now, 50.0, 0.01, markers=1, peak=4095.0, bit_depth=12)
    assert stats.snapshot(now).bit_depth_hint is None


def test_one_bright_16_bit_frame_in_the_window_and_8_bit_frames_never_warn_of_the_depth():
    stats, now = healthy_camera(frames=2)
    stats.frame_processed(now, 50.0, 0.01, markers=1, peak=900.0, bit_depth=16)  # lens cap
    stats.frame_processed(now, 50.0, 0.01, markers=1, peak=40000.0, bit_depth=16)
    assert stats.snapshot(now).bit_depth_hint is None
    dim = CameraStats("cam2", start_ns=0, window_s=10.0)
    dim.frame_processed(S, 50.0, 0.01, markers=0, peak=10.0, bit_depth=0)
    snap = dim.snapshot(S)
    assert snap.bit_depth_hint is None and snap.peak_share == pytest.approx(10.0 / 255.0)
    assert "bit_depth" not in camera_level(snap, LIMITS)[1]


def test_frames_all_under_half_of_white_warn_that_they_are_underexposed():
    stats, now = healthy_camera(frames=2)  # no level reported: not judged
    assert camera_level(stats.snapshot(now), LIMITS) == (OK, "ok")
    for level in (60.0, 80.0):  # 8-bit frames whose white paint stays under half of 255
        stats.frame_processed(now, 50.0, 0.01, markers=1, peak=level, bit_depth=0)
    assert camera_level(stats.snapshot(now), LIMITS) == (
        WARN,
        "frames underexposed: the brightest level is 31 % of white, under 1/2, where markers "
        "are lost: raise the exposure or the gain",
    )
    # One frame exposed for its markers in the window clears it, 16-bit alike.
    stats.frame_processed(now, 50.0, 0.01, markers=1, peak=128.0, bit_depth=0)
    assert camera_level(stats.snapshot(now), LIMITS) == (OK, "ok")
    deep = CameraStats("cam1", start_ns=0, window_s=10.0)
    deep.frame_processed(S, 50.0, 0.01, markers=1, peak=2000.0, bit_depth=12)
    assert "underexposed" in camera_level(deep.snapshot(S), LIMITS)[1]
    deep.frame_processed(S, 50.0, 0.01, markers=1, peak=2048.0, bit_depth=12)
    assert camera_level(deep.snapshot(S), LIMITS)[0] == OK


def test_each_frame_is_judged_by_its_own_white_when_a_camera_changes_its_words():
    # mono8 at 200 of 255, then the driver switches to mono16 of 12-bit levels.
    stats = CameraStats("cam1", start_ns=0, window_s=10.0)
    stats.frame_processed(S, 50.0, 0.01, markers=1, peak=200.0, bit_depth=0)
    stats.frame_processed(S, 50.0, 0.01, markers=1, peak=3200.0, bit_depth=16)
    snap = stats.snapshot(S)
    assert snap.peak_share == pytest.approx(200.0 / 255.0)  # not 200 of 65535
    assert camera_level(snap, LIMITS) == (
        WARN,
        "16-bit frames under 1/16 of white: a 12-bit camera wants detector.bit_depth 12",
    )


def test_header_stamps_that_do_not_advance_warn_with_the_count():
    stats = CameraStats("cam0", start_ns=0, window_s=LIMITS.window_s)
    for i in range(8):  # a driver that leaves the stamp unset
        t = (i + 1) * S // 4
        stats.frame_received(t, stamp_ns=0)
        stats.frame_processed(t, latency_ms=50.0, clock_offset_s=t / S, markers=3)
    assert camera_level(stats.snapshot(2 * S), LIMITS) == (
        WARN,
        "7 of 7 frames in 10 s did not advance the header stamp "
        "(a tracker restarts with a full pass on each)",
    )
    # One repeated stamp in twenty is under the 10 % that warns.
    steady, now = healthy_camera(frames=20)
    steady.frame_received(now + S // 2, stamp_ns=now)
    assert camera_level(steady.snapshot(now + S // 2), LIMITS) == (OK, "ok")


def test_full_frame_passes_are_counted_since_start_and_as_a_share_of_the_window():
    stats = CameraStats("cam0", start_ns=0, window_s=LIMITS.window_s)
    for k, full_frame in enumerate([True, False, False, False, True, False, False, False]):
        t = (k + 1) * 2 * S
        stats.frame_received(t, stamp_ns=t)
        stats.frame_processed(t, 50.0, 0.01, markers=3, full_frame=full_frame)
    now = 17 * S  # the 10 s window holds the last five frames: one full pass
    snap = stats.snapshot(now)
    assert (snap.processed, snap.full_frame_passes) == (8, 2)
    assert snap.full_frame_share == pytest.approx(0.2)
    values = values_of(camera_status("loc", snap, LIMITS))
    assert values["full-frame passes"] == "2"
    assert values["full-frame passes in window (%)"] == "20.0"
    # A count, not a rule: full passes change no level.
    assert camera_level(snap, LIMITS) == (OK, "ok")


def _frames_on_a_clock_standing_still(stats, frames, now_ns):
    """``frames`` more frames at ``now_ns`` (use_sim_time before any /clock): each
    received with a stamp of its own, one in ten replaced, the rest delivered."""
    done = stats.snapshot(now_ns).received
    for k in range(done, done + frames):
        stats.frame_received(now_ns, stamp_ns=k * S // 10)
        if k % 10 == 0:
            stats.frame_replaced(now_ns)
        else:
            stats.frame_processed(now_ns, latency_ms=50.0, clock_offset_s=0.0, markers=1)


def test_a_clock_that_stands_still_keeps_a_cameras_windows_bounded():
    # Measured before the bound: 10 000 and 100 000 frames left 10 000 and 100 000
    # arrivals and stamps in the window, all copied into every snapshot.
    n = 10_000
    stats = CameraStats("cam0", start_ns=0, window_s=10.0)
    _frames_on_a_clock_standing_still(stats, n, 0)
    first = stats.snapshot(0)
    _frames_on_a_clock_standing_still(stats, 9 * n, 0)
    later = stats.snapshot(0)
    assert (first.received_in_window, len(first.window_stamps_ns)) == (n, n)
    # No time passed: no rate (over a span of 1 ns it read 10^13 Hz).
    assert np.isnan(first.input_rate_hz) and np.isnan(first.processed_rate_hz)
    assert later.received == 10 * n
    assert later.received_in_window == len(later.window_stamps_ns) == WINDOW_MAX_FRAMES
    assert later.dropped_in_window <= WINDOW_MAX_FRAMES
    # The stamps kept are the newest, in order.
    assert later.window_stamps_ns[-1] == (10 * n - 1) * S // 10
    assert (np.diff(later.window_stamps_ns) > 0).all()


def test_a_frame_replaced_after_the_clock_went_back_is_no_drop_of_the_restarted_window():
    # play --loop --clock: the last pass's last frame, still in the mailbox, is replaced
    # by the next pass's first, whose arrival restarts the windows (the clock went back).
    stats = CameraStats("cam0", start_ns=0, window_s=10.0)
    for t in (S, 2 * S, 3 * S):
        stats.frame_received(t, stamp_ns=t)
    stats.frame_received(S // 2, stamp_ns=S // 2)
    stats.frame_replaced(S // 2, received_ns=3 * S)
    snap = stats.snapshot(S // 2)
    assert (snap.dropped_mailbox, snap.received_in_window, snap.dropped_in_window) == (1, 1, 0)
    assert camera_level(snap, LIMITS) == (OK, "ok")  # was WARN "100 % of frames dropped"


@pytest.mark.parametrize("first_frame_s", [0.5, 30.0, 1.7e9], ids=["at start", "late", "a bag"])
def test_the_rates_of_a_camera_younger_than_the_window_are_read_over_its_frames(first_frame_s):
    # Counted over the window's length, a bag replayed at its own times (stats from
    # 0, frames from 1.7e9 s) read a 2 Hz camera at 0.6 Hz after 2.5 s.
    stats = CameraStats("cam0", start_ns=0, window_s=10.0)
    first = int(first_frame_s * S)
    for i in range(6):
        t = first + i * S // 2
        stats.frame_received(t, stamp_ns=t)
        stats.frame_processed(t, latency_ms=50.0, clock_offset_s=0.0, markers=1)
    snap = stats.snapshot(first + 5 * S // 2)
    assert snap.input_rate_hz == pytest.approx(2.0) and snap.processed_rate_hz == pytest.approx(2.0)


def test_a_window_holding_more_frames_than_it_keeps_counts_over_the_span_it_keeps():
    stats = CameraStats("cam0", start_ns=0, window_s=10.0, max_window_frames=256)
    for i in range(2000):  # 100 Hz: 1000 frames in the 10 s window
        t = (i + 1) * S // 100
        stats.frame_received(t, stamp_ns=t)
        if i % 10 == 0:
            stats.frame_replaced(t)
        else:
            stats.frame_processed(t, latency_ms=50.0, clock_offset_s=0.0, markers=1)
    snap = stats.snapshot(20 * S)
    assert snap.received_in_window == 256
    assert snap.input_rate_hz == pytest.approx(100.0, rel=0.01)
    assert snap.processed_rate_hz == pytest.approx(90.0, rel=0.02)
    assert snap.dropped_in_window / snap.received_in_window == pytest.approx(0.1, abs=0.01)
    with pytest.raises(ValueError, match="max_window_frames must be at least 1, got 0"):
        CameraStats("cam0", start_ns=0, window_s=10.0, max_window_frames=0)


@pytest.mark.parametrize("rate_hz", [10, 30, 60])
def test_the_processed_rate_counts_every_delivery_of_a_camera_faster_than_20_hz(rate_hz):
    # The rate was counted on the newest 200 results kept for the latency: 20 Hz at
    # most over the 10 s window, whatever the camera's rate.
    stats = CameraStats("cam0", start_ns=0, window_s=10.0)
    for i in range(20 * rate_hz):
        t = (i + 1) * S // rate_hz
        stats.frame_received(t, stamp_ns=t)
        stats.frame_processed(t, latency_ms=50.0, clock_offset_s=0.0, markers=1)
    snap = stats.snapshot(20 * S)
    assert snap.processed_rate_hz == pytest.approx(snap.input_rate_hz)
    assert snap.processed_rate_hz == pytest.approx(rate_hz, rel=0.02)
