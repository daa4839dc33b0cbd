"""The README documents what the code does: every parameter, the two commands."""

from pathlib import Path

import pytest

from marker_localizer.config import DetectorConfig, TrackerConfig, param_specs

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()


@pytest.mark.parametrize("kind", [DetectorConfig, TrackerConfig])
def test_readme_lists_every_detector_and_tracker_parameter_with_its_default_and_text(kind):
    defaults = kind()
    for name, (_, spec) in param_specs(kind).items():
        row = next((line for line in README.splitlines() if line.startswith(f"| `{name}` |")), None)
        assert row is not None, f"{name} missing from the README's parameter table"
        assert f"| {getattr(defaults, name)} |" in row, f"{name}: README default is stale"
        assert f"| {spec.description} |" in row, f"{name}: README description is stale"


def test_ci_runs_exactly_the_readme_test_command():
    assert "./run test" in README and "./run demo" in README
    assert "./run test" in (REPO / ".ci" / "run").read_text()
