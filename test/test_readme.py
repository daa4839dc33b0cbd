"""The README documents what the code does: every parameter, the two commands, what needs ROS."""

import re
from pathlib import Path

import pytest

from marker_localizer.cli import BENCHMARKS, COMMANDS, main
from marker_localizer.config import DetectorConfig, TrackerConfig, param_specs
from marker_localizer.errors import ROS_WHEELS

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


def test_installing_names_the_commands_that_need_ros_and_the_wheels_that_bring_it():
    """A plain ``pip install .`` runs ``detect``; the README says what else needs ROS."""
    installing = README.split("## Installing", 1)[1].split("\n## ", 1)[0]
    assert ROS_WHEELS in " ".join(installing.split())
    # The commands whose modules import ROS (as test_main's import check marks them).
    needs_ros = [name for name, c in COMMANDS.items() if c.module.endswith((".bag", ".demo"))]
    needs_ros += [f"bench {name}" for name, m in BENCHMARKS.items() if m.endswith(".throughput")]
    assert sorted(needs_ros) == ["bench throughput", "demo", "play", "replay", "simulate"]
    assert all(f"`{name}`" in installing for name in needs_ros)


def _command_lines() -> list[list[str]]:
    """The README's ``marker-localizer ...`` lines in its bash blocks, as words."""
    blocks = README.split("```bash\n")[1:]
    lines = [line for block in blocks for line in block.split("```", 1)[0].splitlines()]
    return [line.split() for line in lines if line.startswith("marker-localizer ")]


def test_every_option_a_readme_command_line_shows_is_in_that_commands_help(capsys):
    """An option renamed or removed shows here, not to a newcomer who types the line."""
    pytest.importorskip("rclpy")  # simulate, replay and play load ROS to build their parsers
    lines = _command_lines()
    assert {words[1] for words in lines} >= {"detect", "simulate", "replay", "play"}
    for words in lines:
        command = words[1:3] if words[1] == "bench" else words[1:2]
        with pytest.raises(SystemExit) as exited:
            main([*command, "--help"])
        assert exited.value.code == 0
        shown = set(re.findall(r"--[a-z][a-z-]*", capsys.readouterr().out))
        options = {re.match(r"\[?(--[a-z][a-z-]*)", w).group(1) for w in words if "--" in w}
        assert options <= shown, f"{' '.join(words[:2])}: {sorted(options - shown)} not in --help"
