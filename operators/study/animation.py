"""Animation: the study settings follow the frame, in the viewport and in Render Animation.

The settings live on the study's settings object (:func:`state.settings`), so Blender keyframes,
drivers, the Dope Sheet and the Graph Editor work on them as on any property. What Blender
cannot carry natively (the solid's cutaway mesh, the surface's sampling, the volume material's
eq. 24 inputs, which Python writes) is rebuilt by :func:`pdehead_frame_change`, a persistent
``frame_change_post`` handler:

- it reads each study's settings as the depsgraph it is given evaluated them: the viewport's
  (``frame_set``, playback) or the render's (``render(animation=True)``, ``blender -b -a``),
  whose animated values Blender does not copy back to the original settings;
- it rebuilds only what differs from what the objects were built with, which a
  ``frame_change_pre`` handler notes before Blender evaluates the frame (same frame and
  parameters → no work), and the cutter from its evaluated transform (a keyframed cutter cuts
  every frame);
- Blender re-evaluates what it tagged before it renders the frame (the handler runs in the
  first pass of the frame's update), with ``scene.render.use_lock_interface`` on so the UI
  does not read the meshes while they change.

A study whose rebuild fails (its CT is gone) says so on stderr and in the sidebar, and its
stale object is hidden from that frame's render instead of showing the previous frame's shape.
"""
from __future__ import annotations

import os
import sys
import traceback
from math import tau
from pathlib import Path

import bpy
from mathutils import Matrix

from ...pdehead_addon import PDEHeadError
from .. import compat, state
from ..scene import cutter, render, scene as scene_mod
from ..state import suspended_updates
from ..volume import material as volume_material
from .entity import Study

#: Animatable settings, grouped by what a change rebuilds (:meth:`.Study.live_update`'s ``what``).
GROUPS = {
    "pde": ("continuity", "dome", "smoothing_auto", "smoothing", "approximation_auto", "approximation", "modes"),
    "surface_solid": ("nu", "nv"),
    "surface": ("caps",),
    "solid": ("nw", "u_range", "v_range", "w_range"),
    "volume": ("low_alpha", "high_alpha", "density", "colour_preset", "alpha_mode"),
}
#: The object of each group that must exist for a rebuild to matter.
GROUP_OBJECTS = {"pde": ("surface_object", "solid_object"), "surface_solid": ("surface_object", "solid_object"),
                 "surface": ("surface_object",), "solid": ("solid_object",), "volume": ("volume_object",)}
CUTTER_OWNED = ("u_range", "v_range")  # written by the cutter while Use Cutter is on



def _value(v):
    if isinstance(v, str | bool | int):
        return v
    if isinstance(v, float):
        return round(v, 6)
    try:
        return tuple(round(float(x), 6) for x in v)
    except TypeError:
        return v


def group_values(s, group: str, skip=()) -> tuple:
    return tuple((name, _value(getattr(s, name))) for name in GROUPS[group] if name not in skip)


def _evaluated(id_, depsgraph):
    if depsgraph is None:
        return id_
    try:
        return id_.evaluated_get(depsgraph)
    except (ReferenceError, RuntimeError):
        return id_


def _scene_studies(scene) -> list:
    inside = set(c.name for c in scene.collection.children_recursive)
    return [c for c in state.studies() if c.name in inside]


def forget(study_id: str | None = None) -> None:
    """Drop what the handler remembers (after a file load, or for one removed study)."""
    if study_id is None:
        state.REGISTRY.animation_applied.clear()
        state.REGISTRY.animation_hidden.clear()
    else:
        state.REGISTRY.animation_applied.pop(study_id, None)
        state.REGISTRY.animation_hidden.pop(study_id, None)


def _report_failure(coll, s, group: str, exc: Exception, frame: int) -> None:
    names = set()
    for attr in GROUP_OBJECTS[group]:
        obj = getattr(s, attr)
        if obj is not None and not obj.hide_render:
            obj.hide_render = True
            names.add(obj.name)
    state.REGISTRY.animation_hidden.setdefault(s.study_id, set()).update(names)
    hidden = f"; hidden from the render: {', '.join(sorted(names))}" if names else ""
    message = f"frame {frame}: {group} not rebuilt: {exc}{hidden}"
    with suspended_updates():
        s.last_error = message[:500]
    print(f"PDE Head: study '{coll.name}': {message}", file=sys.stderr)


def _restore_hidden(s) -> None:
    for name in state.REGISTRY.animation_hidden.pop(s.study_id, ()):
        obj = bpy.data.objects.get(name)
        if obj is not None:
            obj.hide_render = False


def apply_frame(scene, depsgraph=None) -> dict[str, list[str]]:
    """Bring every study of ``scene`` to the settings ``depsgraph`` evaluated; returns
    study name -> groups rebuilt (empty when nothing changed)."""
    done: dict[str, list[str]] = {}
    frame = scene.frame_current
    for coll in _scene_studies(scene):
        study = Study.of(coll)
        obj = study.settings_object
        s = obj.pdehead
        frame_s = _evaluated(obj, depsgraph).pdehead
        applied = state.REGISTRY.animation_applied.setdefault(s.study_id, {})  # filled by the frame_change_pre handler
        box = cutter.cutter_of(coll) if s.use_cutter else None
        skip = CUTTER_OWNED if box is not None else ()
        rebuilt, failed = _apply_groups(study, frame_s, applied, skip, frame)
        if box is not None:
            cut, cut_failed = _apply_cutter(study, box, depsgraph, applied, skip, frame)
            rebuilt += cut
            failed = failed or cut_failed
        if rebuilt and not failed:
            _restore_hidden(s)
            if s.last_error:
                with suspended_updates():
                    s.last_error = ""
        if rebuilt:
            done[coll.name] = rebuilt
    return done


def _apply_groups(study: Study, frame_s, applied: dict, skip, frame: int) -> tuple[list[str], bool]:
    """Copy each group's evaluated values (``frame_s``) that changed since ``applied`` onto the study's settings
    and rebuild the group's objects; returns (groups rebuilt, whether one failed)."""
    coll, s = study.collection, study.settings_object.pdehead
    rebuilt: list[str] = []
    failed = False
    for group in GROUPS:
        values = group_values(frame_s, group, skip)
        if group not in applied:
            applied[group] = group_values(s, group, skip)  # what the objects were last built with
        if values == applied[group]:
            continue
        applied[group] = values
        with suspended_updates():
            for name, _ in values:
                new = getattr(frame_s, name)
                if _value(getattr(s, name)) != _value(new):
                    setattr(s, name, new if isinstance(new, str | bool | int | float) else tuple(new))
        if not any(getattr(s, attr) is not None for attr in GROUP_OBJECTS[group]):
            continue
        try:
            _rebuild(study, group)
            rebuilt.append(group)
        except Exception as exc:  # noqa: BLE001 - a handler must never raise into Blender
            if not isinstance(exc, PDEHeadError):
                traceback.print_exc()
            _report_failure(coll, s, group, exc, frame)
            failed = True
    return rebuilt, failed


def _apply_cutter(study: Study, box, depsgraph, applied: dict, skip, frame: int) -> tuple[list[str], bool]:
    """Re-cut the solid when the cutter box's evaluated matrix changed; returns (["cutter"] or [], whether it
    failed)."""
    coll, s = study.collection, study.settings_object.pdehead
    matrix = _evaluated(box, depsgraph).matrix_world.copy()
    cache = study.cache
    if cache.cutter_signature == cutter.signature(box, matrix):
        return [], False
    try:
        study.apply_cutter(matrix)
        applied["solid"] = group_values(s, "solid", skip)
        return ["cutter"], False
    except Exception as exc:  # noqa: BLE001 - a handler must never raise into Blender
        cache.cutter_signature = cutter.signature(box, matrix)
        if not isinstance(exc, PDEHeadError):
            traceback.print_exc()
        _report_failure(coll, s, "solid", exc, frame)
        return [], True


def _rebuild(study: Study, group: str) -> None:
    """Rebuild one group like the sidebar's live update, but raising instead of recording the error."""
    s = study.settings
    if group == "volume":
        volume_material.set_volume_settings(s.volume_object, **study.volume_settings())
        return
    if group == "pde" and s.volume_object is not None:
        s.volume_stale = True
    if group in ("surface", "surface_solid", "pde") and s.surface_object is not None:
        study.surface()
        if group == "pde":
            study.detail_out_of_date()
    if group in ("solid", "surface_solid", "pde") and s.solid_object is not None:
        study.solid()


def note_built(scene) -> None:
    """Remember the settings every study of ``scene`` is built with now: its original settings, before
    Blender evaluates the new frame (live updates and this handler keep the objects in step with them)."""
    for coll in _scene_studies(scene):
        s = state.settings(coll)
        skip = CUTTER_OWNED if s.use_cutter and cutter.cutter_of(coll) is not None else ()
        state.REGISTRY.animation_applied[s.study_id] = {group: group_values(s, group, skip) for group in GROUPS}


@bpy.app.handlers.persistent
def pdehead_frame_change_pre(scene, depsgraph=None) -> None:
    """``frame_change_pre``: what each study is built with, before the frame's values arrive."""
    if state.running.now("animation") or state.updates_suspended():
        return
    try:
        note_built(scene)
    except Exception:  # noqa: BLE001
        traceback.print_exc()


@bpy.app.handlers.persistent
def pdehead_frame_change(scene, depsgraph=None) -> None:
    """``frame_change_post``: every study of the scene shows the frame's settings (see the module)."""
    if state.running.now("animation") or state.updates_suspended():
        return
    with state.running("animation"):
        try:
            apply_frame(scene, depsgraph)
        except Exception:  # noqa: BLE001 - never raise into Blender (playback, rendering)
            traceback.print_exc()


@bpy.app.handlers.persistent
def pdehead_migrate_load_post(*_args) -> None:
    """``load_post`` (runs before the other PDE Head handlers): settings saved by 0.1.0 on a study's
    collection move to its settings object; the frame handler starts afresh."""
    forget()
    try:
        for name in state.migrate_legacy_settings():
            print(f"PDE Head: study '{name}': settings of a file saved by PDE Head 0.1.0 moved to its "
                  "settings object (animatable)", file=sys.stderr)
        for scene in bpy.data.scenes:
            if _scene_studies(scene):
                scene.render.use_lock_interface = True
    except Exception:  # noqa: BLE001 - a load handler must never stop the load
        traceback.print_exc()


_HANDLERS = (("frame_change_pre", pdehead_frame_change_pre), ("frame_change_post", pdehead_frame_change),
             ("load_post", pdehead_migrate_load_post))


def _remove_handlers() -> None:
    for kind, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, kind)
        for h in list(handlers):
            if getattr(h, "__name__", "") == fn.__name__:
                handlers.remove(h)


def register() -> None:
    _remove_handlers()
    bpy.app.handlers.frame_change_pre.append(pdehead_frame_change_pre)
    bpy.app.handlers.frame_change_post.append(pdehead_frame_change)
    bpy.app.handlers.load_post.insert(0, pdehead_migrate_load_post)  # before the handlers that read studies


def unregister() -> None:
    _remove_handlers()
    forget()



# ------------------------------------------------------------------------------------------
# A turntable in one click

TURNTABLE_KIND = "turntable"


def turntable(context, coll, frames: int, start: int = 1):
    """A camera orbit of ``frames`` frames around study ``coll``: its camera (Frame Study's, made first if needed)
    and key light (its fill light rides the camera) are parented to a pivot Empty "<study> Turntable" at the head's
    centre whose Z rotation is keyed linearly from 0 (frame ``start``) to 360° (frame ``start + frames``), so the
    frames ``start`` … ``start + frames - 1`` (the scene's new frame range) loop seamlessly. Returns the pivot."""


    if frames < 2:
        raise PDEHeadError(f"a turntable needs at least 2 frames, got {frames}")
    scene = context.scene
    s = state.settings(coll)
    cam = scene_mod.study_object(coll, scene_mod.CAMERA_KIND)
    if cam is None:
        scene_mod.frame_study(context, coll)
        cam = scene_mod.study_object(coll, scene_mod.CAMERA_KIND)
    shown = [o for o in (s.surface_object, s.solid_object, s.volume_object) if o is not None and not o.hide_render]
    shown = shown or [o for o in (s.surface_object, s.solid_object, s.volume_object) if o is not None]
    lo, hi = render.world_bounds(shown)
    centre = 0.5 * (lo + hi)

    pivot = scene_mod.study_object(coll, TURNTABLE_KIND)
    if pivot is None:
        pivot = bpy.data.objects.new(f"{coll.name} Turntable", None)
        pivot["pdehead_kind"] = TURNTABLE_KIND
        pivot.empty_display_type = "SPHERE"
        coll.objects.link(pivot)
    pivot.animation_data_clear()
    pivot.empty_display_size = 0.25 * float(max(hi - lo))
    pivot.rotation_mode = "XYZ"
    pivot.rotation_euler = (0.0, 0.0, 0.0)
    pivot.location = centre
    pivot.scale = (1.0, 1.0, 1.0)
    at_rest = Matrix.Translation(centre)
    # the camera and the key light ride the pivot: the lit side turns with the camera, not away from it
    for rider in (cam, scene_mod.study_object(coll, scene_mod.LIGHT_KIND)):
        if rider is None:
            continue
        world = rider.matrix_world.copy()
        if rider.parent is not None and rider.parent != pivot:
            rider.parent = None
        rider.parent = pivot
        rider.matrix_parent_inverse = at_rest.inverted()
        rider.matrix_basis = world  # pivot at rest @ parent inverse = identity: it stays where it was
    pivot.keyframe_insert("rotation_euler", index=2, frame=start)
    pivot.rotation_euler[2] = tau
    pivot.keyframe_insert("rotation_euler", index=2, frame=start + frames)
    pivot.rotation_euler[2] = 0.0
    for fcurve in compat.animation_fcurves(pivot):
        for key in fcurve.keyframe_points:
            key.interpolation = "LINEAR"
    scene.camera = cam
    scene.frame_start, scene.frame_end = start, start + frames - 1
    scene.frame_set(start)
    return pivot


def render_animation(scene, folder, resolution: tuple[int, int] = (320, 320), samples: int = 16) -> list:
    """Render the scene's frame range with Cycles (CPU) to ``folder/frame_0001.png`` …; returns the paths.

    ``folder`` is created if needed; an ``OSError`` says when it cannot be written."""
    folder = Path(os.fspath(folder))
    folder.mkdir(parents=True, exist_ok=True)
    if not os.access(folder, os.W_OK):
        raise PermissionError(f"{folder}: folder is not writable")
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(samples)
    scene.render.resolution_x, scene.render.resolution_y = (int(r) for r in resolution)
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.use_file_extension = True
    scene.render.filepath = str(folder / "frame_")
    bpy.ops.render.render(animation=True)
    return [folder / f"frame_{f:04d}.png" for f in range(scene.frame_start, scene.frame_end + 1, scene.frame_step)]
