"""The thread counts of the OpenBLAS libraries loaded in this process, read and set."""

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
