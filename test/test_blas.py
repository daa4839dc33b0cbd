"""One BLAS thread for a process that detects."""

import ctypes
import shutil
from pathlib import Path

import numpy as np
from blas_threads import openblas_threads, set_openblas_threads

from marker_localizer.blas import _mapped_path, single_thread_blas


def test_single_thread_blas_leaves_every_loaded_openblas_one_thread():
    np.ones((64, 64)) @ np.ones((64, 64))
    set_openblas_threads(2)
    limited = single_thread_blas()
    # numpy's and scipy's wheels each bring an OpenBLAS.
    assert len(limited) >= 2
    assert sorted(openblas_threads()) == limited
    assert set(openblas_threads().values()) == {1}


def _load_a_copy_of_numpys_openblas(copy: Path) -> str:
    """Load numpy's OpenBLAS again from ``copy``; the path of numpy's own."""
    np.ones((64, 64)) @ np.ones((64, 64))
    numpys = next(path for path in openblas_threads() if "numpy" in path)
    copy.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(numpys, copy)
    ctypes.CDLL(str(copy))
    return numpys


def test_an_openblas_under_a_folder_whose_name_holds_spaces_is_limited_too(tmp_path):
    """A venv under such a folder: /proc/self/maps gives the path with its spaces."""
    copy = tmp_path / "my projects" / "a venv" / "libopenblas_copy.so"
    _load_a_copy_of_numpys_openblas(copy)
    set_openblas_threads(2)
    assert str(copy) in single_thread_blas()
    assert openblas_threads()[str(copy)] == 1


def test_a_maps_line_gives_its_path_whole_and_a_deleted_file_none():
    start = "7f1c2a000000-7f1c2a200000 r-xp 00000000 fe:00 1234"
    spaced = "/home/a b/venv/libopenblas.so"
    assert _mapped_path(f"{start}    {spaced}\n") == spaced
    assert _mapped_path(f"{start}    /opt/libopenblas.so (deleted)\n") == ""
    assert _mapped_path("7f1c2a000000-7f1c2a200000 rw-p 00000000 00:00 0\n") == ""


def test_an_openblas_deleted_since_it_was_loaded_is_passed_over(tmp_path):
    """A venv reinstalled under a running node: a worker started then still maps the old one."""
    copy = tmp_path / "libopenblas_gone.so"
    numpys = _load_a_copy_of_numpys_openblas(copy)
    copy.unlink()
    limited = single_thread_blas()
    assert numpys in limited
    assert not any("libopenblas_gone" in path for path in limited)
