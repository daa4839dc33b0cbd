"""The thread counts of the OpenBLAS libraries loaded in this process, read and set."""

import pytest

from marker_localizer.blas import _OPENBLAS_SETTERS, library_function, loaded_openblas

_GETTERS = tuple(name.replace("_set_", "_get_") for name in _OPENBLAS_SETTERS)


def openblas_threads() -> dict[str, int]:
    """Each loaded OpenBLAS (that tells) by path: its thread count."""
    counts = {}
    for path, library in loaded_openblas().items():
        getter = library_function(library, _GETTERS)
        if getter is not None:
            counts[path] = getter()
    return counts


def set_openblas_threads(count: int) -> None:
    """Give every loaded OpenBLAS ``count`` threads."""
    for library in loaded_openblas().values():
        setter = library_function(library, _OPENBLAS_SETTERS)
        if setter is not None:
            setter(count)


def two_threaded_openblas() -> list[str]:
    """Give every loaded OpenBLAS two threads; the paths of those that took them.

    Skips the test where none does (a BLAS without OpenBLAS's setters, or one core).
    """
    set_openblas_threads(2)
    threaded = [library for library, count in openblas_threads().items() if count == 2]
    if not threaded:
        pytest.skip("no OpenBLAS here takes a second thread")
    return threaded
