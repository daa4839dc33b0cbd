"""One BLAS thread for a process that detects."""

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
