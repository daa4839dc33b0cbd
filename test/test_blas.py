"""One BLAS thread for a process that detects."""

import ctypes
import shutil

import numpy as np
from blas_threads import openblas_threads, set_openblas_threads

from marker_localizer.blas import single_thread_blas


def test_single_thread_blas_leaves_every_loaded_openblas_one_thread():
    np.ones((64, 64)) @ np.ones((64, 64))
    set_openblas_threads(2)
    limited = single_thread_blas()
    # numpy's and scipy's wheels each bring an OpenBLAS.
    assert len(limited) >= 2
    assert sorted(openblas_threads()) == limited
    assert set(openblas_threads().values()) == {1}


def test_an_openblas_under_a_folder_whose_name_holds_spaces_is_limited_too(tmp_path):
    """A venv under such a folder: /proc/self/maps gives the path with its spaces."""
    np.ones((64, 64)) @ np.ones((64, 64))
    numpys = next(path for path in openblas_threads() if "numpy" in path)
    folder = tmp_path / "my projects" / "a venv"
    folder.mkdir(parents=True)
    copy = folder / "libopenblas_copy.so"
    shutil.copy(numpys, copy)
    ctypes.CDLL(str(copy))
    set_openblas_threads(2)
    assert str(copy) in single_thread_blas()
    assert openblas_threads()[str(copy)] == 1
