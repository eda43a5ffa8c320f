"""The engine's two-thread helpers: the same result as one thread, and a cancel that leaves no thread running."""
import threading
import time

import numpy as np
import pytest

from pdehead_addon.core.threads import in_slabs, map_in_order


def test_in_slabs_covers_every_index_once():
    seen = np.zeros(101, int)

    def work(a, b):
        seen[a:b] += 1
    in_slabs(101, work, parts=3)
    assert (seen == 1).all()


def test_map_in_order_hands_results_in_the_items_order():
    got = []

    def slow_first(x):
        time.sleep(0.02 if x == 0 else 0.0)      # the first item finishes last
        return x * x
    map_in_order(slow_first, list(range(7)), lambda n, r: got.append((n, r)))
    assert got == [(n, n * n) for n in range(7)]


def test_a_raise_in_each_drops_the_items_not_started_and_no_thread_runs_on():
    started, running = [], threading.Event()

    def work(x):
        started.append(x)
        running.set()
        time.sleep(0.01)
        running.clear()
        return x

    def each(n, _):
        if n == 1:
            raise KeyboardInterrupt("cancelled")
    with pytest.raises(KeyboardInterrupt):
        map_in_order(work, list(range(50)), each)
    count = len(started)
    assert not running.is_set()                  # every started item had finished when the raise went on
    time.sleep(0.05)
    assert len(started) == count < 50            # and nothing started afterwards
