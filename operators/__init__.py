"""Everything of PDE Head that touches bpy: registration of the whole Blender layer.

``register()`` adds the property groups, preferences, operators (with the File > Import menu entry), the sidebar
panels, the save/load handlers of :mod:`.study.persistence`, the cutter's depsgraph handler (:mod:`.study.handlers`, and
the face's of :mod:`.study.face_handler`), the frame handler and settings migration of :mod:`.study.animation`
and one ``load_post``
handler that frees the in-memory caches of studies that are not in the newly loaded file. ``unregister()`` removes
all of it again, leaving no class, property, menu entry, handler or timer behind.
"""
from __future__ import annotations

import traceback

import bpy

from . import prefs, state
from .forensic import props as forensic_props
from .scene import detail_map
from .study import animation, face_handler, handlers as study_handlers, persistence, props
from .ui import forensic_ops, ops, panel


@bpy.app.handlers.persistent
def pdehead_load_post(*_args) -> None:
    """After a file is loaded: forget cached CT/segmentations of studies it does not contain."""
    present = {state.settings(c).study_id for c in state.studies()}
    try:                                  # a file saved with the CT detail as bump: the displacement now
        detail_map.reopen_with_displacement()
    except Exception:  # noqa: BLE001 - a load handler must never stop the load
        traceback.print_exc()
    for study_id in state.cached_study_ids():
        if study_id not in present:
            state.drop_cache(study_id)


#: Every class of the Blender layer, registered once in this order (parent panels before their
#: children) and unregistered in reverse.
CLASSES = (*props.CLASSES, *prefs.CLASSES, *ops.CLASSES, *panel.CLASSES, *forensic_ops.CLASSES)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    props.attach()
    forensic_props.register()
    ops.add_menu()
    persistence.register()
    study_handlers.register()
    face_handler.register()
    bpy.app.handlers.load_post.append(pdehead_load_post)
    animation.register()


def unregister() -> None:
    animation.unregister()
    for handler in list(bpy.app.handlers.load_post):
        if getattr(handler, "__name__", "") == "pdehead_load_post":
            bpy.app.handlers.load_post.remove(handler)
    face_handler.unregister()
    study_handlers.unregister()
    persistence.unregister()
    ops.remove_menu()
    forensic_props.unregister()
    props.detach()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    state.drop_cache()
