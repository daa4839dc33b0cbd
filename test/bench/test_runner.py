"""What every benchmark's command line does around its run."""

import json

import pytest

from marker_localizer.bench.runner import run_and_save
from marker_localizer.errors import ConfigError


def test_a_json_path_that_cannot_be_written_is_refused_before_the_run(tmp_path):
    ran = []
    with pytest.raises(ConfigError, match=r"--json .*x\.json: cannot write it"):
        run_and_save("x", lambda report: ran.append(1) or {}, tmp_path / "missing" / "x.json")
    assert ran == []  # not after minutes of work
    path = tmp_path / "x.json"
    assert run_and_save("x", lambda report: {"figure": 1}, path) == 0
    assert json.loads(path.read_text())["figure"] == 1
