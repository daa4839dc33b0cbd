"""The thread counts of the OpenBLAS libraries loaded in this process, read and set."""

import ctypes

from marker_localizer.blas import _OPENBLAS_SETTERS, _mapped_path

_GETTERS = tuple(name.replace("_set_", "_get_") for name in _OPENBLAS_SETTERS)


def _loaded() -> dict[str, ctypes.CDLL]:
    with open("/proc/self/maps") as maps:
        paths = {_mapped_path(line) for line in maps if "openblas" in line.lower()}
    return {path: ctypes.CDLL(path) for path in sorted(p for p in paths if p.startswith("/"))}


def openblas_threads() -> dict[str, int]:
    """Each loaded OpenBLAS (that tells) by path: its thread count."""
    counts = {}
    for path, library in _loaded().items():
        getter = next((getattr(library, n) for n in _GETTERS if hasattr(library, n)), None)
        if getter is not None:
            counts[path] = getter()
    return counts


def set_openblas_threads(count: int) -> None:
    """Give every loaded OpenBLAS ``count`` threads."""
    for library in _loaded().values():
        setter = next((getattr(library, n) for n in _OPENBLAS_SETTERS if hasattr(library, n)), None)
        if setter is not None:
            setter(count)
