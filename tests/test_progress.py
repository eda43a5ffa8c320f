"""Progress and cancel of the engine's long steps: a callback reports, and may raise Cancelled to stop.

A cancelled step returns nothing and leaves nothing: its worker threads are gone, its input is
unchanged, and a later run gives the same result as one never interrupted.
"""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from pdehead_addon import Cancelled, extract_boundaries, segment_head
from pdehead_addon.pde.pde_solid import w_field
from pdehead_addon.pde.pde_surface import solve_pde
from pdehead_addon.pde.solid_ct_table import SolidCTTable


def _timer_cancel(run, delay: float):
    """Run ``run(progress)`` with a threading.Timer that asks for a cancel after ``delay`` seconds.

    Returns (raised Cancelled?, fractions reported, the fraction at which it stopped)."""
    stop = threading.Event()
    seen: list[float] = []

    def progress(fraction, message):
        assert isinstance(message, str)
        seen.append(fraction)
        if stop.is_set():
            raise Cancelled()

    timer = threading.Timer(delay, stop.set)
    timer.start()
    try:
        run(progress)
        cancelled = False
    except Cancelled:
        cancelled = True
    finally:
        timer.cancel()
    return cancelled, seen


def test_a_timer_cancels_segment_head_half_way_and_nothing_is_left(phantom):
    ct = phantom.ct
    data = ct.data.copy()
    fractions: list[float] = []
    t0 = time.perf_counter()
    full = segment_head(ct, progress=lambda f, m: fractions.append(f))
    duration = time.perf_counter() - t0
    # reported often, in order, from 0 to 1
    assert len(fractions) >= 10 and fractions[0] == 0.0 and fractions[-1] == 1.0
    assert np.all(np.diff(fractions) >= 0)
    threads_before = threading.active_count()
    delay = duration / 2
    for _ in range(5):  # a busy machine may run faster or slower this time: half-way, else earlier
        cancelled, seen = _timer_cancel(lambda p: segment_head(ct, progress=p), delay)
        if cancelled:
            break
        delay /= 3
    assert cancelled, "the timer never caught segment_head before it finished"
    assert 0.0 < seen[-1] < 1.0                   # stopped in the middle, not at the end
    # nothing left: the solver's worker threads are gone, the CT is untouched
    for _ in range(50):
        if threading.active_count() <= threads_before:
            break
        time.sleep(0.02)
    assert threading.active_count() <= threads_before
    np.testing.assert_array_equal(ct.data, data)
    # and a new run gives the uninterrupted result (no state carried over)
    again = segment_head(ct)
    np.testing.assert_array_equal(again.mask, full.mask)


def test_boundaries_w_field_and_the_ct_table_report_and_cancel(phantom):
    seg = segment_head(phantom.ct)
    seen: list[float] = []
    bset = extract_boundaries(seg, patches=6, samples=128, progress=lambda f, m: seen.append(f))
    assert seen[0] == 0.0 and seen[-1] == 1.0 and len(seen) >= 4 and np.all(np.diff(seen) >= 0)
    head = solve_pde(bset)

    def cancel_at(limit):
        calls = []

        def progress(fraction, message):
            calls.append(fraction)
            if len(calls) >= limit:
                raise Cancelled()
        return progress, calls

    for run in (lambda p: extract_boundaries(seg, patches=6, samples=128, progress=p),
                lambda p: w_field(head, 3.0, ct=phantom.ct, progress=p),
                lambda p: SolidCTTable(head, phantom.ct, progress=p)):
        progress, calls = cancel_at(2)
        with pytest.raises(Cancelled):
            run(progress)
        assert len(calls) == 2 and calls[-1] < 1.0


def test_the_band_fine_level_reports_and_cancels(phantom, monkeypatch):
    """Issue 20: grids of >= chan_vese_pyramid.FINE_BAND_MIN_VOXELS solve the full-resolution level in a band
    (chan_vese_band.band_fine_solve); it reports every iteration and a Cancelled raised there stops the
    segmentation, after which a new run gives the uninterrupted result."""
    from pdehead_addon import CTVolume
    from pdehead_addon.segment import chan_vese_pyramid
    data = phantom.ct.data
    air = float(np.median(np.concatenate([data[:, 0].ravel(), data[:, -1].ravel()])))
    ct = CTVolume(np.pad(data, ((1, 1), (22, 24), (22, 24)), constant_values=air), phantom.ct.spacing)
    monkeypatch.setattr(chan_vese_pyramid, "FINE_BAND_MIN_VOXELS", ct.data.size)     # this small grid uses the band
    in_band = []
    solve = chan_vese_pyramid.band_fine_solve

    def spy(*args, **kwargs):
        in_band.append(True)
        return solve(*args, **kwargs)
    monkeypatch.setattr(chan_vese_pyramid, "band_fine_solve", spy)
    full = segment_head(ct, levels_mm=(6.0,))
    assert in_band and full.meta["solver"].get("fine_band"), full.meta["solver"]
    reports = []

    def progress(fraction, message):
        if in_band and "Chan-Vese iteration" in message:
            reports.append(fraction)
            if len(reports) == 2:
                raise Cancelled()
    in_band.clear()
    with pytest.raises(Cancelled):
        segment_head(ct, levels_mm=(6.0,), progress=progress)
    assert len(reports) == 2 and 0.0 < reports[0] < reports[1] < 1.0
    again = segment_head(ct, levels_mm=(6.0,))
    np.testing.assert_array_equal(again.mask, full.mask)


@pytest.mark.parametrize("stage", ["preparing the full-resolution band", "thin attachments", "holes and cavities"])
def test_the_band_set_up_and_the_clean_up_report_and_cancel(phantom, monkeypatch, stage):
    """Issue 20: on the clinical scan the band's set-up (~1.5 s) and the mask's clean-up (~2 s) ran without a
    report, so Ctrl-C waited 3.4 s for the next one. Each now reports its stages; a Cancelled raised at one
    stops the segmentation there (no later stage is reached), and a new run gives the uninterrupted result."""
    from pdehead_addon import CTVolume
    from pdehead_addon.segment import chan_vese_pyramid
    data = phantom.ct.data
    air = float(np.median(np.concatenate([data[:, 0].ravel(), data[:, -1].ravel()])))
    ct = CTVolume(np.pad(data, ((1, 1), (22, 24), (22, 24)), constant_values=air), phantom.ct.spacing)
    monkeypatch.setattr(chan_vese_pyramid, "FINE_BAND_MIN_VOXELS", ct.data.size)     # this small grid uses the band
    full = segment_head(ct, levels_mm=(6.0,))
    messages = []

    def progress(fraction, message):
        messages.append(message)
        if message == stage:
            raise Cancelled()
    with pytest.raises(Cancelled):
        segment_head(ct, levels_mm=(6.0,), progress=progress)
    assert messages[-1] == stage
    assert "segmentation done" not in messages and "finding the neck" not in messages
    if stage != "preparing the full-resolution band":
        assert "cleaning up the head mask" in messages
    again = segment_head(ct, levels_mm=(6.0,))
    np.testing.assert_array_equal(again.mask, full.mask)
