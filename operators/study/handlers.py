"""The handler every study shares: a moved cutter re-cuts its study's solid (and, on unregister, the end
of the colour-refresh timer of :mod:`.live`).

:func:`pdehead_cutter_update` runs after each depsgraph update (moving the cutter in the viewport,
from Python or during playback) and applies each study's cutter whose transform changed
(:meth:`.entity.Study.apply_cutter`); an unchanged scene costs one comparison per study.
"""
from __future__ import annotations

import traceback

import bpy

from ...pdehead_addon import PDEHeadError
from .. import state
from ..scene import cutter
from . import live as study_live
from .entity import Study


@bpy.app.handlers.persistent
def pdehead_cutter_update(_scene, depsgraph=None) -> None:
    """After a depsgraph update: apply each study's cutter whose transform changed."""
    if state.running.now("studies"):
        return
    with state.running("studies"):
        for coll in state.studies():
            study = Study.of(coll)
            s = study.settings
            if not s.use_cutter:
                continue
            box = cutter.cutter_of(coll)
            if box is None:
                continue
            cache = study.cache
            if cache.cutter_signature == cutter.signature(box):
                continue
            try:
                study.apply_cutter()  # sets last_error ('' or a notice about the colours)
            except Exception as exc:  # noqa: BLE001 - a handler must not raise into Blender
                cache.cutter_signature = cutter.signature(box)  # do not retry every update
                if not isinstance(exc, PDEHeadError):
                    traceback.print_exc()
                s.last_error = f"cutter: {exc}"[:500]


def register() -> None:
    state.install_depsgraph_handler(pdehead_cutter_update)


def unregister() -> None:
    state.remove_depsgraph_handler(pdehead_cutter_update)
    study_live.cancel_colour_refresh()
