"""Timing for the benches: the best of a few runs of a call, in seconds (on a shared machine the best run is the
one least disturbed by other work)."""

import time

import numpy as np


def best_time(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        started = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - started)
    return best
