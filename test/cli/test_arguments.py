"""Counts, seeds, durations and keys on the command line: refused where they are read."""

import pytest

from marker_localizer.bench import accuracy, bound, speed
from marker_localizer.cli import main

REFUSED = [
    (["demo", "--seed", "-1"], "--seed: must be at least 0, got -1"),
    (["simulate", "--out", "never", "--seed", "-3"], "--seed: must be at least 0, got -3"),
    (["demo", "--frames", "0"], "--frames: must be at least 1, got 0"),
    (["simulate", "--out", "never", "--frames", "0"], "--frames: must be at least 1, got 0"),
    (["simulate", "--out", "never", "--width", "-4"], "--width: must be at least 1, got -4"),
    (["bench", "accuracy", "--frames", "-1"], "--frames: must be at least 1, got -1"),
    (["bench", "accuracy", "--seed", "-1"], "--seed: must be at least 0, got -1"),
    (["bench", "speed", "--frames", "0"], "--frames: must be at least 1, got 0"),
    (["bench", "speed", "--repeats", "0"], "--repeats: must be at least 1, got 0"),
    (["bench", "speed", "--seed", "x"], "--seed: expected an integer, got 'x'"),
    (
        ["bench", "speed", "--subjects", "ours,nope"],
        "--subjects: unknown subjects ['nope', 'ours']",
    ),
    (["bench", "accuracy", "--families", "a,zz"], "--families: unknown families ['zz']"),
    (["bench", "bound", "--frames", "0"], "--frames: must be at least 1, got 0"),
    (["bench", "bound", "--first-seed", "-1"], "--first-seed: must be at least 0, got -1"),
    (["bench", "paper", "--seed", "-1"], "--seed: must be at least 0, got -1"),
    (["bench", "throughput", "--workers", "1", "0"], "--workers: must be at least 1, got 0"),
    (["bench", "throughput", "--width", "0"], "--width: must be at least 1, got 0"),
    (
        ["bench", "throughput", "--seconds", "0"],
        "--seconds: must be a finite number above 0, got 0",
    ),
    (
        ["bench", "throughput", "--rate-hz", "nan"],
        "--rate-hz: must be a finite number above 0, got nan",
    ),
]


@pytest.mark.parametrize(("argv", "message"), REFUSED, ids=[" ".join(a) for a, _ in REFUSED])
def test_a_count_seed_or_duration_out_of_range_is_a_usage_error_naming_the_option(
    argv, message, capsys
):
    """Before, a negative seed ended in numpy's traceback, a count of 0 in an empty
    table or in a run that failed after minutes of rendering."""
    if argv[0] in ("demo", "simulate") or argv[1] == "throughput":
        pytest.importorskip("rclpy")
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert f"argument {message}" in capsys.readouterr().err


# Each benchmark's parser alone: before, two of these ran the benchmark.
EMPTY_LISTS = [
    (accuracy.parse_args, ["--families", ""], "--families", "a,b,c,d,e,g,dull,ground"),
    (bound.main, ["--families", " , "], "--families", "a,b,c,d,g"),
    (speed.parse_args, ["--subjects", ""], "--subjects", "symmetry,ncc"),
]


@pytest.mark.parametrize(
    ("parse", "argv", "option", "choices"),
    EMPTY_LISTS,
    ids=[f"{parse.__module__.rsplit('.', 1)[1]} {' '.join(a)}" for parse, a, _, _ in EMPTY_LISTS],
)
def test_an_empty_list_of_keys_is_a_usage_error_naming_the_option_and_its_choices(
    parse, argv, option, choices, capsys
):
    """Before, an empty list ran every subject in speed, no family in accuracy (a table of
    no figures), and was refused in bound alone."""
    with pytest.raises(SystemExit) as exit_info:
        parse(argv)
    assert exit_info.value.code == 2
    assert f"argument {option}: give at least one of: {choices}" in capsys.readouterr().err
