"""A run's process uses one OpenBLAS thread (executive/threads.py): numpy's and scipy's copies both, including one
set to more threads before the run was built."""

from __future__ import annotations

import os

import numpy as np
import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS)

from kitchenbot.executive import threads


def _set_all(n: int) -> None:
    for lib in threads._loaded_openblas():
        fn = threads._symbol(lib, "set_num_threads")
        if fn is not None:
            fn(n)


def test_building_a_run_leaves_every_openblas_one_thread(make_runner, monkeypatch):
    assert threads._loaded_openblas(), "numpy's OpenBLAS should be loaded"
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    _set_all(2)  # as OpenBLAS starts on a computer with two cores or more
    runner, _ = make_runner()
    counts = threads.blas_threads()
    assert counts and all(c == 1 for c in counts), counts
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"  # a copy loaded later starts with one thread
    # the arithmetic is unchanged: a product of the sizes the pipeline multiplies, bit for bit
    rng = np.random.default_rng(0)
    A, R = rng.normal(size=(900, 3)), rng.normal(size=(3, 3))
    one = A @ R.T
    _set_all(2)
    assert np.array_equal(one, A @ R.T)
    threads.limit_blas_threads()


def test_a_thread_count_the_user_set_is_kept(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    assert threads.limit_blas_threads() == 2
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    assert threads.limit_blas_threads() == 1
