"""One BLAS thread for a process that detects: the detector's matrices are small.

The detector's matrix products and solves are a few hundred rows each. OpenBLAS
runs them on as many threads as there are cores, and its threads spin while they
wait for the next one: a detection takes as long on one thread and half the
processor time (docs/speed.md, "Worker processes" and "One BLAS thread for the
command line"), and processes detecting side by side compete with each
other's spinning threads. The processes this package owns take one thread: the
node's (its ``main``) and its worker processes, ``marker-localizer detect`` and
``replay``; a program that calls the library decides for itself
(``OPENBLAS_NUM_THREADS=1`` before numpy loads, or :func:`single_thread_blas`).
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import Any

#: OpenBLAS's setter of its thread count, by build: numpy's and scipy's wheels
#: (scipy-openblas, 64- and 32-bit integers), older wheels, the distributions' libopenblas.
_OPENBLAS_SETTERS = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)

#: What /proc/self/maps appends to the path of a file deleted since it was mapped.
_DELETED = " (deleted)"


def single_thread_blas() -> list[str]:
    """Limit every OpenBLAS loaded in this process to one thread, from now on.

    ``OPENBLAS_NUM_THREADS`` acts only before numpy loads, so the loaded
    libraries are asked instead (:func:`loaded_openblas`); another BLAS (MKL) is
    left as it is.

    Returns:
        The paths of the libraries limited.
    """
    limited = []
    for path, library in loaded_openblas().items():
        setter = library_function(library, _OPENBLAS_SETTERS)
        if setter is not None:
            setter(1)
            limited.append(path)
    return limited


def loaded_openblas() -> dict[str, ctypes.CDLL]:
    """Every OpenBLAS mapped into this process that can be opened, by path, in path order.

    Linux only: the libraries are found in /proc/self/maps (none elsewhere).
    """
    try:
        with open("/proc/self/maps") as maps:
            paths = {_mapped_path(line) for line in maps if "openblas" in line.lower()}
    except OSError:
        return {}
    libraries = {}
    for path in sorted(p for p in paths if p.startswith("/")):
        try:
            libraries[path] = ctypes.CDLL(path)
        except OSError:  # gone or unreadable since it was mapped: nothing to ask
            continue
    return libraries


def library_function(library: ctypes.CDLL, names: Sequence[str]) -> Any | None:
    """The first of ``names`` that ``library`` exports (builds name their symbols apart)."""
    return next((getattr(library, name) for name in names if hasattr(library, name)), None)


def _mapped_path(line: str) -> str:
    """The file a line of /proc/self/maps maps ("" for none): its sixth field, spaces and all.

    Address, permissions, offset, device and inode come first; a venv under a folder
    whose name holds a space puts spaces in the path. A file deleted since it was
    mapped (a venv reinstalled under a running node) is marked " (deleted)": there
    is no file left to ask, and it reads as none.
    """
    fields = line.rstrip("\n").split(maxsplit=5)
    if len(fields) < 6 or fields[5].endswith(_DELETED):
        return ""
    return fields[5]
