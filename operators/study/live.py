"""The solid and the live updates of a study, as methods of :class:`.entity.Study` (this module's mixin).

A live parameter changed in the sidebar (the update callbacks of :mod:`.props`), a moved cutter and the
frame handler rebuild the study's existing objects without re-segmenting: :meth:`LiveSolid.live_update`,
:meth:`LiveSolid.apply_cutter`. A live change of the PDE rebuilds the solid's geometry at once with the
CT colours of the previous solution's table and re-tabulates the CT in a timer right after
(:meth:`LiveSolid.refresh_solid_colours`, :meth:`LiveSolid.flush_colour_refresh`).
"""
from __future__ import annotations

import time
import traceback

import bpy
import numpy as np
from mathutils import Matrix

from ...pdehead_addon import PDEHeadError
from .. import state
from ..outcome import StepOutcome
from ..scene import cutter, detail_map, objects
from ..state import suspended_updates
from ..volume import material as volume_material

#: The studies whose solid waits for its CT colours: ``state.REGISTRY.colours_pending``, study id -> (time of
#: the last live change, the Study).
_REFRESH_DELAY_S = 0.15   # a slider still moving within this time keeps postponing the refresh


def _schedule_colour_refresh() -> None:
    if not bpy.app.timers.is_registered(_colour_refresh_timer):
        bpy.app.timers.register(_colour_refresh_timer, first_interval=_REFRESH_DELAY_S)


def cancel_colour_refresh() -> None:
    """Forget every waiting colour refresh and remove its timer (the add-on's unregister: no timer left behind)."""
    state.REGISTRY.colours_pending.clear()
    if bpy.app.timers.is_registered(_colour_refresh_timer):
        bpy.app.timers.unregister(_colour_refresh_timer)


def _colour_refresh_timer():
    """bpy.app.timers callback: the CT colours of every solid left waiting by a live change."""
    now = time.monotonic()
    if any(now - t < _REFRESH_DELAY_S for t, _study in state.REGISTRY.colours_pending.values()):
        return _REFRESH_DELAY_S  # still dragging: come back
    LiveSolid.flush_colour_refresh()
    return None


class LiveSolid:
    """Mixin of :class:`.entity.Study`: the solid (exact or deferred CT colours), live updates, the cutter."""

    #: A live change of the PDE (smoothing, modes, ...) rebuilds the solid's geometry at once with the CT
    #: colours of the previous solution's table and re-tabulates the CT in a timer right after
    #: (:meth:`refresh_solid_colours`). None: when Blender has a UI (in background mode -- scripts, the
    #: CLI, tests -- the colours are made at once, as there is no event loop to run the timer).
    DEFER_CT_COLOURS: bool | None = None

    @classmethod
    def defer_ct_colours(cls) -> bool:
        return (not bpy.app.background) if cls.DEFER_CT_COLOURS is None else bool(cls.DEFER_CT_COLOURS)

    def colours_pending(self) -> bool:
        """True while the study's solid waits for its exact CT colours."""
        return self.study_id in state.REGISTRY.colours_pending

    def _colours_wait(self) -> None:
        state.REGISTRY.colours_pending[self.study_id] = (time.monotonic(), self)
        _schedule_colour_refresh()

    def _solid_table(self, head, live: bool) -> tuple:
        """``(table, window, ct, notice)`` for :meth:`solid`: the CT table of this PDE solution, else the
        previous one's (a live change, or no CT to tabulate), with its window; the CT when it was read."""
        table = self.current_ct_table()
        cache = self.cache
        window = cache.window or cache.stored_window
        ct, notice = None, ""
        deferred = live and self.defer_ct_colours()
        if table is not None:
            if deferred and cache.ct is not None:
                # while a slider moves, the cut faces come from the (u, v, w) table in 128-pixel
                # tiles (the geometry step stays within a frame); the timer right after redraws them from the CT
                self._colours_wait()
            else:
                state.REGISTRY.colours_pending.pop(self.study_id, None)
            return table, window, ct, notice
        if deferred:
            previous = self.previous_ct_table()
            if previous is not None:
                table, window = previous
            self._colours_wait()
            return table, window, ct, notice
        try:
            ct = self.ct  # re-read after reopening: a solid without its CT colours is a loss
        except PDEHeadError as exc:
            previous = self.previous_ct_table()
            if previous is None:
                raise
            table, window = previous
            notice = (f"the solid's CT colours are those of the previous PDE solution (the table saved in "
                      f"the file): {exc}").replace("; nothing was changed", "")
        if ct is not None:
            window = self.ct_window(ct)
            with state.Timer() as t:
                table = self.ct_table(head, ct)
            self.record_timing("ct_table", t.seconds)   # target: at most 1 s with the w-field
            state.REGISTRY.colours_pending.pop(self.study_id, None)
        return table, window, ct, notice

    def solid(self, live: bool = False) -> StepOutcome:
        """Build or rebuild the solid; returns the solid object, its vertex count (``values["vertices"]``), the
        seconds of the build and the notice for the sidebar (``values["notice"]``, '' when the colours are
        exact; also the outcome's one warning).

        With ``live`` and :meth:`defer_ct_colours`, a solid whose PDE solution has no CT table yet
        gets the previous table's colours now and the exact ones from :meth:`refresh_solid_colours`.
        Without the CT (a file sent without it), the table stored in the .blend serves; when even
        that belongs to another PDE solution, the geometry still follows the surface and the notice
        says the colours are approximate.
        """
        s = self.settings
        head = self.solve()
        table, window, ct, notice = self._solid_table(head, live)
        quick = live and self.defer_ct_colours()
        cut_ct = None
        if not quick and table is not None:        # the cut faces at the CT's own resolution
            cut_ct = ct if ct is not None else self.cache.ct
            if cut_ct is None:
                try:
                    cut_ct = self.ct
                except PDEHeadError:
                    cut_ct = None                  # a file sent without its CT: the table's resolution
        coll = self.collection
        with state.Timer() as t:
            s.solid_object = objects.build_solid(
                head, coll, nu=s.nu, nv=s.nv, nw=s.nw, u_range=tuple(s.u_range), v_range=tuple(s.v_range),
                w_range=tuple(s.w_range), ct=None, obj=s.solid_object, name=f"{coll.name} Solid",
                window=window if table is not None else None, ct_table=table, texture_size=128 if quick else None,
                cut_ct=cut_ct, texture_budget=s.ct_texture_budget, skin=s.solid_skin,
                skin_depth_mm=s.solid_skin_depth)
        self.record_timing("solid", t.seconds)
        return StepOutcome("solid", objects=(s.solid_object,), warnings=(notice,) if notice else (),
                           seconds=t.seconds, values=dict(vertices=len(s.solid_object.data.vertices), notice=notice))

    def refresh_solid_colours(self) -> None:
        """Tabulate the CT for the current PDE solution and rebuild the solid with its exact colours.

        What a live change deferred (:meth:`solid` with ``live``); errors go to the sidebar.
        """
        s = self.settings
        state.REGISTRY.colours_pending.pop(self.study_id, None)
        if s.solid_object is None:
            return
        try:
            s.last_error = self.solid().values["notice"]
        except Exception as exc:  # noqa: BLE001 - runs from a timer: never raise into Blender
            if not isinstance(exc, PDEHeadError):
                traceback.print_exc()
            s.last_error = f"the solid's CT colours could not be updated: {exc}"[:500]

    @staticmethod
    def flush_colour_refresh() -> int:
        """Give every waiting solid its exact CT colours now (the timer, and before a save); returns the count."""
        count = 0
        for study_id, (_t, study) in list(state.REGISTRY.colours_pending.items()):
            coll = next((c for c in state.studies() if state.settings(c).study_id == study_id), None)
            if coll is None:
                state.REGISTRY.colours_pending.pop(study_id, None)
                continue
            type(study).of(coll).refresh_solid_colours()
            count += 1
        return count

    # --- live parameters (the update callbacks in props.py) and the cutter ------------------------

    def _start_manual_controls(self) -> None:
        """A manual smoothing/approximation slider starts from the automatic value (as a fraction of the
        study's range)."""
        s = self.settings
        if self.boundary_set() is None or (s.smoothing_auto and s.approximation_auto):
            return
        smoothing, approximation = self.default_controls()
        with suspended_updates():
            if not s.smoothing_auto and not s.is_property_set("smoothing"):
                s.smoothing = smoothing
            if not s.approximation_auto and not s.is_property_set("approximation"):
                s.approximation = approximation

    def live_update(self, what: str) -> None:
        """Rebuild the study's existing objects after a live parameter changed (no re-segmenting).

        ``what``: "pde_auto", "pde", "surface", "solid", "surface_solid", "volume" or "cutter". Errors
        cannot be reported from an update callback: they go to ``settings.last_error`` (shown in the
        sidebar) and the console.
        """
        s = self.settings
        notice = ""
        try:
            if what == "pde_auto":
                what = "pde"
                self._start_manual_controls()
            if what == "cutter":
                if s.use_cutter and cutter.cutter_of(self.collection) is not None:
                    self.apply_cutter()
            elif what == "volume":
                if s.volume_object is not None:
                    volume_material.set_volume_settings(s.volume_object, **self.volume_settings())
            else:
                if what == "pde" and s.volume_object is not None:
                    s.volume_stale = True  # the w-field follows the PDE; rebuilt on request (heavy)
                if what in ("surface", "surface_solid", "pde") and s.surface_object is not None:
                    self.surface()
                    if what == "pde":
                        self.detail_out_of_date()
                if what in ("solid", "surface_solid", "pde") and s.solid_object is not None:
                    notice = self.solid(live=True).values["notice"]
            s.last_error = notice[:500]
        except Exception as exc:  # noqa: BLE001 - an update callback must never raise into the UI
            if not isinstance(exc, PDEHeadError):
                traceback.print_exc()
            s.last_error = str(exc)[:500]
            print(f"PDE Head: live update of {what} failed: {exc}")

    def detail_out_of_date(self) -> None:
        """The PDE moved the surface away from its CT detail map: the bump is unplugged and the map marked
        out of date (rebuilding costs seconds, far beyond a slider's step: :mod:`operators.scene.detail_map`)."""
        s = self.settings
        if s.surface_object is not None and detail_map.set_detail_shading(s.surface_object, s.detail_strength, False):
            with suspended_updates():
                s.detail_stale = True

    def apply_cutter(self, matrix=None) -> str:
        """Set the study's u/v ranges from its cutter and rebuild the solid; returns the cut's kind.

        ``matrix``: the cutter's world matrix to cut with (default its own; the frame handler passes
        the one the render's depsgraph evaluated)."""
        s = self.settings
        box = cutter.cutter_of(self.collection)
        if box is None:
            raise PDEHeadError(f"study '{self.name}' has no cutter: add one first")
        matrix = box.matrix_world if matrix is None else matrix
        head = self.head
        # world metres = LPS mm * 0.001, so LPS mm -> cutter local = inverse(matrix_world) @ scale(0.001)
        inverse = np.array(matrix.inverted_safe() @ Matrix.Scale(0.001, 4))
        u_range, v_range, _kept, kind = cutter.cutter_ranges(head, inverse, float(box.empty_display_size))
        with suspended_updates():
            s.u_range, s.v_range = u_range, v_range
        self.cache.cutter_signature = cutter.signature(box, matrix)
        s.last_error = self.solid(live=True).values["notice"][:500] if s.solid_object is not None else ""
        return kind

    def add_cutter(self, context):
        """A cutter box for the study (the solid built first if needed), applied at once: (empty, cut kind)."""
        if self.settings.solid_object is None:
            self.solid()
        obj = cutter.add_cutter(context, self.collection)
        return obj, self.apply_cutter()
