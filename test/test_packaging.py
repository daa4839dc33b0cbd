"""What pip, colcon and rosdep read: declared ranges, the test extra, package.xml."""

import re
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def pins(path: Path) -> dict[str, str]:
    lines = path.read_text().splitlines()
    return dict(line.split("==") for line in lines if "==" in line and not line.startswith("#"))


def test_setup_py_lower_bounds_are_the_lowest_versions_tested():
    block = re.search(r"install_requires=\[(.*?)\]", (REPO / "setup.py").read_text(), re.S)
    bounds = dict(re.findall(r'"([A-Za-z0-9_.-]+)>=([0-9.]+)"', block[1]))
    assert bounds == pins(REPO / "requirements-lowest.txt")


def test_every_runtime_requirement_is_pinned_within_its_declared_range():
    lowest, pinned = pins(REPO / "requirements-lowest.txt"), pins(REPO / "requirements.txt")
    for name, low in lowest.items():
        version = tuple(int(part) for part in pinned[name].split("."))
        assert version >= tuple(int(part) for part in low.split(".")), name


def test_package_xml_names_every_ros_package_the_code_imports():
    depends = {e.text for e in ET.parse(REPO / "package.xml").getroot() if "depend" in e.tag}
    code = "\n".join(p.read_text() for p in (REPO / "marker_localizer").rglob("*.py"))
    ros_import = r"^\s*(?:from|import) (rclpy|\w+_msgs|\w+_interfaces)\b"
    imported = set(re.findall(ros_import, code, re.M))
    assert imported <= depends, imported - depends
    assert "tf2_msgs" in depends  # play publishes /tf_static, whose package the code imports late
