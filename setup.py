"""ament_python package marker_localizer; also installs with plain pip."""

from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "marker_localizer"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (
            f"share/{PACKAGE}/config",
            sorted(str(p) for pattern in ("*.yaml", "*.xml") for p in Path("config").glob(pattern)),
        ),
    ],
    python_requires=">=3.11",
    # Lower bounds: requirements-lowest.txt, tested by ./run test (as are the newest).
    install_requires=[
        "numpy>=1.26.4",
        "scipy>=1.11.4",
        "opencv-python-headless>=4.6.0.66",
        "scikit-image>=0.22.0",
        "rosbags>=0.11.6",
        "PyYAML>=6.0.1",
    ],
    # colcon test runs pytest only for a package that declares it as its test extra.
    extras_require={"test": ["pytest"]},
    zip_safe=True,
    # No person or address has been named for this package yet; the .invalid domain
    # (RFC 2606) says so rather than pass for a real address. package.xml says the same.
    maintainer="not yet named",
    maintainer_email="maintainer-not-yet-named@marker-localizer.invalid",
    description="Sub-pixel localisation of diagonal (X) ground markers for UAV navigation.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "marker-localizer = marker_localizer.cli:main",
            "marker_localizer_node = marker_localizer.node:main",
        ],
    },
)
