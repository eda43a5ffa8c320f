"""Work on two threads: the engine's one thread count, slabs of a volume, chunks in order.

numpy releases the GIL in its large loops, so independent chunks of one array operation run side by
side on the benchmarks' two-core machines; each helper here gives the same result as one thread.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence

import numpy as np

__all__ = ["THREADS", "in_slabs", "map_in_order"]

#: Threads of the engine's parallel steps (the machines of the benchmarks have two cores).
THREADS = min(2, os.cpu_count() or 1)


def in_slabs(n: int, work, parts: int | None = None) -> None:
    """``work(a, b)`` on ``parts`` (default :data:`THREADS`) consecutive ranges of ``range(n)``, one
    per thread (numpy releases the GIL in its loops); the first exception is raised."""
    parts = max(1, min(THREADS if parts is None else int(parts), int(n)))
    cuts = np.linspace(0, n, parts + 1).round().astype(int)
    if parts == 1:
        work(0, int(n))
        return
    with ThreadPoolExecutor(parts) as pool:
        list(pool.map(lambda k: work(int(cuts[k]), int(cuts[k + 1])), range(parts)))


def map_in_order(work: Callable, items: Sequence, each: Callable[[int, object], None]) -> None:
    """``each(n, work(items[n]))`` for every item in order, ``work`` on :data:`THREADS` threads.

    ``each`` runs on the calling thread (progress, placing results); when it raises (a cancel from a
    progress callback) the items not yet started are dropped and the running ones finish before the
    exception goes on, so no thread still writes into the caller's arrays afterwards.
    """
    pool = ThreadPoolExecutor(max(1, min(THREADS, len(items))))
    try:
        for n, result in enumerate(pool.map(work, items)):
            each(n, result)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
