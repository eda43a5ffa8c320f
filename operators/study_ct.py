"""A study's CT: kept in memory, re-read from its recorded source when needed, its intensity window
and the CT tabulated in the solid's (u, v, w) (in memory and, for saving, in the .blend).
"""
from __future__ import annotations

import json

from ..pdehead_addon import PDEHeadError
from . import state
from .progress import step_progress
from .study_entity import Study


def require_ct(collection):
    """The study's CT volume from memory, else re-read from its recorded source (:func:`reload_ct`).

    Raises a :class:`PDEHeadError` that names the missing source when it cannot be re-read,
    so a step that needs the CT (solid colours, volume, segmentation) never runs without it.
    """
    s = state.settings(collection)
    ct = state.cache_for(s.study_id).ct
    if ct is None:
        ct = reload_ct(collection)
    return ct


def reload_ct(collection):
    """Load the CT again from the recorded source (phantom or path + the recorded loader options).

    The re-read CT must have the recorded dimensions; a different CT at that path is refused
    (its colours would not belong to this study's head).
    """
    s = state.settings(collection)
    cache = state.cache_for(s.study_id)
    if s.source_kind == "PHANTOM":
        from ..pdehead_addon import make_phantom
        ct = make_phantom().ct
    elif s.source_kind == "FILES":
        path = Study.of(collection).resolve_source()
        if path is None:
            raise PDEHeadError(Study.of(collection).source_missing_message())
        from ..pdehead_addon import load_ct
        options = json.loads(s.load_options or "{}")
        for key in ("shape", "spacing", "resample_spacing"):
            if isinstance(options.get(key), list):
                options[key] = tuple(options[key])
        ct = load_ct(path, **options)
    else:
        raise PDEHeadError(f"study '{collection.name}': the CT is not in memory and has no source to reload")
    nz, ny, nx = ct.shape
    expected = tuple(int(n) for n in s.dimensions)
    if any(expected) and (nx, ny, nz) != expected:
        raise PDEHeadError(f"study '{collection.name}': the CT re-read from {s.source or 'the phantom'} has "
                           f"{nx} x {ny} x {nz} voxels, the study was built from {' x '.join(map(str, expected))}; "
                           "refusing to mix them (point Source at the original CT)")
    cache.ct = ct
    cache.window = None
    cache.ct_table = None
    return ct


def current_ct_table(collection):
    """The solid's CT table for the study's current PDE solution, from memory or from the .blend, or None.

    A table saved in the .blend (:func:`store_ct_table_for_save`) is used when it was tabulated
    for the same curves and controls: a reopened file, or one sent without its CT, keeps live
    cutaways and nw without reading the CT. Its window becomes the study's window when none is known.
    """
    cache = state.cache_for(state.settings(collection).study_id)
    key = Study.of(collection).table_key()
    if cache.ct_table is not None and cache.ct_table[0] == key:
        return cache.ct_table[1]
    if Study.of(collection).stored_ct_table_key() == key:
        stored = Study.of(collection).load_stored_ct_table()
        if stored is not None:
            cache.ct_table = (key, stored[1])
            if cache.window is None:
                cache.window = stored[2]
            cache.stored_window = stored[2]
            return stored[1]
    return None


def previous_ct_table(collection):
    """``(table, window)`` of an earlier PDE solution of this study (memory, else the .blend), or None.

    Looked up in (u, v, w), it gives the new solid nearly the right colours at once (the
    parameterisation moves little with a control); :func:`refresh_solid_colours` replaces them.
    """
    cache = state.cache_for(state.settings(collection).study_id)
    if cache.ct_table is not None:
        window = cache.window or cache.stored_window
        if window is not None:
            return cache.ct_table[1], window
    stored = Study.of(collection).load_stored_ct_table()
    if stored is not None:
        cache.stored_window = stored[2]
        return stored[1], (cache.window or stored[2])
    return None


def ct_table(collection, head, ct):
    """The CT tabulated in the solid's (u, v, w) for this PDE solution (built once, ~0.5-1.3 s on CThead).

    Kept until the PDE is re-solved with other controls or curves, or the CT is re-read, so
    cutaway and resolution sliders only look values up.
    """
    table = current_ct_table(collection)
    if table is None:
        from ..pdehead_addon import SolidCTTable
        table = SolidCTTable(head, ct, progress=step_progress("solid"))
        state.cache_for(state.settings(collection).study_id).ct_table = (Study.of(collection).table_key(), table)
    return table


def store_ct_table_for_save(collection) -> int:
    """Put the current CT table into the .blend unless it is there already (save_pre); returns bytes written."""
    s = state.settings(collection)
    if s.solid_object is None:
        return 0
    cache = state.cache_for(s.study_id)
    key = Study.of(collection).table_key()
    if cache.ct_table is None or cache.ct_table[0] != key or Study.of(collection).stored_ct_table_key() == key:
        return 0
    window = cache.window or cache.stored_window
    if window is None:
        return 0
    return Study.of(collection).store_ct_table(key, cache.ct_table[1], window)


def ct_window(collection, ct=None) -> tuple[float, float]:
    """The study's CT intensity window (:func:`ct_volume.intensity_window`), computed once per CT."""
    cache = state.cache_for(state.settings(collection).study_id)
    if cache.window is None:
        from ..pdehead_addon import intensity_window
        cache.window = intensity_window(ct if ct is not None else require_ct(collection))
    return cache.window
