"""The face's live re-solve: the ``depsgraph_update_post`` handler that re-solves a face whose pegs moved, and
the update callback of the study's face table (the face itself: :mod:`.face`)."""
from __future__ import annotations

import bpy

from .. import state
from ..forensic.face import FACE_KEY
from ..forensic.study import ForensicStudy
from .entity import Study


def forensic_of(coll):
    """The forensic side (:class:`.study.ForensicStudy`) of a study collection."""
    return ForensicStudy.of(Study.of(coll))


def live_table(coll) -> None:
    """Update callback of the study settings ``face_table`` / ``face_table_file`` (:mod:`operators.study.props`)."""
    forensic_of(coll).face.live_table()


@bpy.app.handlers.persistent
def pdehead_face_update(_scene, depsgraph=None) -> None:
    """After a depsgraph update: re-solve each study's face whose peg tips moved since its last solve.

    A scene without a face costs one key lookup per study; a face whose pegs did not move, one
    matrix read per peg.
    """
    if state.running.now("face") or state.updates_suspended():
        return
    with state.running("face"):
        for coll in state.studies():
            if FACE_KEY not in coll:
                continue
            fs = forensic_of(coll)
            obj = fs.face.face_object()
            if obj is None or obj.mode == 'EDIT':      # edited by hand: Blender's edit mesh would overwrite it
                continue
            try:
                tips = fs.face.moved_tips()
                if tips is not None:
                    fs.face.solve_face(tips=tips)
            except Exception as exc:  # noqa: BLE001 - a handler must not raise into Blender
                if fs.face.face_object() is not None:      # do not retry on every update: remember the tips tried
                    fs.cache["face_tips"] = fs.face.peg_tips(fs.face.face_peg_names())
                fs.settings.last_error = f"face: {exc}"[:500]
                print(f"PDE Head: face of '{coll.name}' not updated: {exc}")


def register() -> None:
    state.install_depsgraph_handler(pdehead_face_update)


def unregister() -> None:
    state.remove_depsgraph_handler(pdehead_face_update)
    state.REGISTRY.face_tables.clear()
