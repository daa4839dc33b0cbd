"""The paper-reproduction benchmark (marker_localizer.bench.paper) on small rendered frames."""

from __future__ import annotations

from scenes import SMALL_SCENE

from marker_localizer.bench import accuracy, paper, peers
from marker_localizer.synthetic import render_checkerboard, render_scene


def test_both_pipelines_run_on_the_same_frames_and_the_targets_are_judged():
    markers = [
        accuracy.LabelledFrame.rendered(render_scene(SMALL_SCENE, seed), (8.0, 16.0))
        for seed in (1, 2)
    ]
    board = render_checkerboard((360, 480), (5, 4), 36.0, tilt_deg=20.0, seed=3)
    sets = [
        paper.ReproductionSet("rendered (a)", markers, "markers"),
        paper.ReproductionSet(
            "boards", [accuracy.LabelledFrame.rendered(board, (24.0, 40.0))], "boards"
        ),
    ]
    rows = paper.evaluate(sets, seed=0)
    assert [r.name for r in rows["rendered (a)"]] == [d.name for d in paper.PIPELINES]
    assert all(r.tally.frames == 2 and r.tally.n_truth == 8 for r in rows["rendered (a)"])
    table = paper.reproduction_table(rows)
    assert peers.PAPER_ROW in table and "boards" in table
    verdicts = paper.targets(sets, rows)
    assert len(verdicts) == 2 and all(v.endswith(": met") for v in verdicts)


def test_the_papers_pipeline_is_a_row_of_the_accuracy_benchmark():
    names = [v.name for v in peers.our_variants()]
    assert peers.PAPER_ROW in names
    chosen = next(v for v in peers.our_variants() if v.name == peers.PAPER_ROW)
    config = chosen.detector((6.0, 40.0)).config
    assert (config.candidate_detector, config.refinement) == ("curvature", "ncc")
