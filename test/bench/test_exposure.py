"""The exposure benchmark (marker_localizer.bench.exposure) on small rendered frames."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scenes import SMALL_SCENE

from marker_localizer.bench import accuracy, exposure
from marker_localizer.synthetic import render_scene


def test_over_exposure_multiplies_the_levels_rounds_them_and_clips_them_at_white():
    frame = np.array([[0, 1, 100, 127, 128, 200]], np.uint8)
    np.testing.assert_array_equal(exposure.over_exposed(frame, 2.0), [[0, 2, 200, 254, 255, 255]])
    np.testing.assert_array_equal(exposure.over_exposed(frame, 0.3), [[0, 0, 30, 38, 38, 60]])
    assert exposure.over_exposed(frame, 2.0).dtype == np.uint8


@pytest.mark.parametrize(
    ("frame", "gain"),
    [(np.zeros((4, 4), np.uint16), 2.0), (np.zeros((4, 4), np.uint8), 0.0)],
)
def test_over_exposure_refuses_a_frame_not_8_bit_and_a_gain_not_above_zero(frame, gain):
    with pytest.raises(ValueError):
        exposure.over_exposed(frame, gain)


@pytest.fixture
def small_rendered(monkeypatch) -> accuracy.Family:
    """The benchmark's rendered sets narrowed to one small family of two frames."""
    family = accuracy.Family(
        "t", "test", (8.0, 16.0), 2, 2, lambda seed: render_scene(SMALL_SCENE, seed)
    )
    monkeypatch.setattr(exposure, "families", lambda: [family])
    monkeypatch.setattr(exposure, "RENDERED_FAMILIES", ("t",))
    return family


def test_at_its_own_exposure_a_frame_reads_as_the_accuracy_benchmark_reads_it(small_rendered):
    reports: list[str] = []
    figures = exposure.run(exposure.Options(gains=(1.0, 3.0)), reports.append)
    frames = [
        accuracy.LabelledFrame.rendered(small_rendered.render(i), small_rendered.radius_range)
        for i in range(2)
    ]
    tally = accuracy.evaluate_frames(frames, 0, accuracy.reference_detectors()).rows[0].tally
    read = figures["rendered (t), 2 frames"][accuracy.REFERENCE_ROW]
    assert read["1"] == {"recall": tally.recall, "fp_per_frame": tally.fp_per_frame}
    assert set(read) == {"1", "3"}
    assert "independent and real sets" in reports[0]
    table = reports[-1]
    assert "gain 1" in table and "gain 3" in table
    assert f"{tally.recall:.1%} ({tally.fp_per_frame:.2f})" in table


def test_over_exposed_frames_are_what_every_detector_reads(small_rendered, monkeypatch):
    # Three times over, most of the rendered white clips: the frames the detectors are
    # given hold those levels, not the frames as rendered.
    seen: list[np.ndarray] = []

    def recording_evaluate(frames, seed, detectors):
        seen.extend(f.image for f in frames)
        return accuracy.evaluate_frames(frames, seed, detectors)

    monkeypatch.setattr(exposure, "evaluate_frames", recording_evaluate)
    exposure.run(exposure.Options(gains=(3.0,)), lambda text: None)
    rendered = [small_rendered.render(i).image for i in range(2)]
    for image, original in zip(seen, rendered, strict=True):
        np.testing.assert_array_equal(image, exposure.over_exposed(original, 3.0))
        assert (image == exposure.WHITE_DN).mean() > (original == exposure.WHITE_DN).mean()


def test_main_saves_the_figures_of_every_gain(small_rendered, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(exposure.real_data, "data_root", lambda: None)
    path = tmp_path / "exposure.json"
    assert exposure.main(["--gains", "1,2", "--json", str(path)]) == 0
    saved = json.loads(path.read_text())
    assert set(saved["rendered (t), 2 frames"][accuracy.REFERENCE_ROW]) == {"1", "2"}
    assert "exposure benchmark finished" in capsys.readouterr().out


@pytest.mark.parametrize("gains", ["0", "1,-2", "two"])
def test_main_refuses_a_gain_not_above_zero(gains, capsys):
    with pytest.raises(SystemExit) as exit_info:
        exposure.main(["--gains", gains])
    assert exit_info.value.code == 2
    assert "--gains" in capsys.readouterr().err
