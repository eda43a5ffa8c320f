"""Everything of PDE Head that touches bpy: registration of the whole Blender layer.

``register()`` adds the property groups, preferences, operators (with the File > Import
menu entry), the sidebar panels, the save/load handlers of :mod:`.persistence`, the cutter's
depsgraph handler (:mod:`.study`) and one ``load_post`` handler that frees the in-memory caches
of studies that are not in the newly loaded file. ``unregister()`` removes all of it again,
leaving no class, property, menu entry, handler or timer behind.
"""
from __future__ import annotations

import bpy

from . import forensic, ops, panel, persistence, prefs, props, state, study


@bpy.app.handlers.persistent
def pdehead_load_post(*_args) -> None:
    """After a file is loaded: forget cached CT/segmentations of studies it does not contain."""
    present = {state.settings(c).study_id for c in state.studies()}
    for study_id in state.cached_study_ids():
        if study_id not in present:
            state.drop_cache(study_id)


#: Registered in this order, unregistered in reverse.
_MODULES = (props, prefs, ops, panel, forensic, persistence, study)


def register() -> None:
    for mod in _MODULES:
        mod.register()
    bpy.app.handlers.load_post.append(pdehead_load_post)


def unregister() -> None:
    for handler in list(bpy.app.handlers.load_post):
        if getattr(handler, "__name__", "") == "pdehead_load_post":
            bpy.app.handlers.load_post.remove(handler)
    for mod in reversed(_MODULES):
        mod.unregister()
    state.drop_cache()
