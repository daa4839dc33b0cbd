"""What every benchmark's command line does around its run."""

import json
import os
import resource
import signal

import pytest

from marker_localizer.bench.runner import run_and_save
from marker_localizer.errors import ConfigError, OutputError


def test_a_json_path_that_cannot_be_written_is_refused_before_the_run(tmp_path):
    ran = []
    with pytest.raises(ConfigError, match=r"--json .*x\.json: cannot write it"):
        run_and_save("x", lambda report: ran.append(1) or {}, tmp_path / "missing" / "x.json")
    assert ran == []  # not after minutes of work
    path = tmp_path / "x.json"
    assert run_and_save("x", lambda report: {"figure": 1}, path) == 0
    assert json.loads(path.read_text())["figure"] == 1


def _failing_run(report):
    raise RuntimeError("the benchmark failed")


def test_a_failed_run_leaves_no_json_file_behind(tmp_path):
    """Before, the check before the run left an empty file that read as a run that saved
    nothing."""
    path = tmp_path / "x.json"
    with pytest.raises(RuntimeError, match="the benchmark failed"):
        run_and_save("x", _failing_run, path)
    assert not path.exists()


def test_a_failed_run_leaves_a_json_file_that_was_there_as_it_was(tmp_path):
    path = tmp_path / "x.json"
    path.write_text('{"figure": 1}')
    os.utime(path, ns=(1_000_000_000, 1_000_000_000))
    with pytest.raises(RuntimeError, match="the benchmark failed"):
        run_and_save("x", _failing_run, path)
    assert path.read_text() == '{"figure": 1}'
    assert path.stat().st_mtime_ns == 1_000_000_000


def test_figures_that_cannot_be_written_leave_the_earlier_file_whole_and_say_why(tmp_path):
    """Written in place, a full disk cut an earlier run's file short, in a traceback."""
    path = tmp_path / "x.json"
    path.write_text('{"figure": 1}')
    # A file size limit of 1 KiB, the signal it raises ignored: writes fail as on a full disk.
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limits = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (1024, limits[1]))
    try:
        with pytest.raises(
            OutputError, match=r"--json .*x\.json: cannot write it \(File too large"
        ):
            run_and_save("x", lambda report: {"figures": list(range(1000))}, path)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, limits)
        signal.signal(signal.SIGXFSZ, previous)
    assert path.read_text() == '{"figure": 1}'
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]
