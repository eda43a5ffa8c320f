"""The 3D View sidebar tab "PDE Head": one panel per pipeline step plus the last run's timings."""
from __future__ import annotations

import os

import bpy

from .. import state
from ..study.entity import Study


class _PDEHeadPanel:
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "PDE Head"

    @staticmethod
    def study(context) -> Study | None:
        return Study.active(context)


class _StudyPanel(_PDEHeadPanel):
    """Panels shown only when there is a study."""

    @classmethod
    def poll(cls, context):
        return state.active_study(context) is not None


class PDEHEAD_PT_study(_PDEHeadPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_study"
    bl_label = "Study"

    def draw(self, context):
        layout = self.layout
        layout.prop(context.scene.pdehead, "active_study", text="")
        row = layout.row(align=True)
        row.operator("pdehead.import_ct", text="Import CT", icon='IMPORT')
        row.operator("pdehead.load_phantom", text="Phantom", icon='USER')
        study = self.study(context)
        if study is None:
            layout.label(text="No study yet: import a CT or load the phantom", icon='INFO')
            return
        s = study.settings
        col = layout.column(align=True)
        nx, ny, nz = s.dimensions
        col.label(text=f"Dimensions: {nx} x {ny} x {nz}")
        dz, dy, dx = s.spacing
        col.label(text=f"Spacing: {dx:g} x {dy:g} x {dz:g} mm")
        lo, hi = s.value_range
        col.label(text=f"Range: {lo:.0f} .. {hi:.0f}" + (" HU" if s.modality in ("CT", "HU") else ""))
        if s.series:
            col.label(text=f"Series: {s.series}")
        source = "phantom" if s.source_kind == "PHANTOM" else (os.path.basename(s.source.rstrip("/\\")) or s.source)
        col.label(text=f"Source: {source}")
        for note in study.notes[:2]:        # automatic choices, in the dialog's words
            col.label(text=state.user_text(note)[:160], icon='INFO')
        for warning in study.warnings[:4]:  # one line each, in the dialog's words
            col.label(text=state.user_text(warning)[:160], icon='ERROR')
        text, icon = study.ct_status()
        col.label(text=text[:160], icon=icon)
        if icon == 'ERROR':  # the CT moved: let the user point the study at it again
            layout.prop(s, "source", text="CT Source")
        layout.separator()
        op = layout.operator("pdehead.run_pipeline", text="Run Whole Pipeline", icon='PLAY')
        op.source = 'ACTIVE'
        layout.operator("pdehead.frame_study", icon='CAMERA_DATA')
        layout.operator("pdehead.turntable", icon='FILE_REFRESH')
        if s.last_error:
            layout.label(text=s.last_error[:120], icon='ERROR')
        layout.operator("pdehead.remove_study", icon='TRASH')


class PDEHEAD_PT_segmentation(_StudyPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_segmentation"
    bl_label = "Segmentation"

    def draw(self, context):
        layout = self.layout
        s = self.study(context).settings
        layout.operator("pdehead.segment", icon='MOD_MASK')
        if s.seg_iterations:
            col = layout.column(align=True)
            col.label(text=f"Head: {100 * s.seg_fraction:.1f} % of voxels")
            col.label(text=f"c1 {s.seg_c1:.3g}, c2 {s.seg_c2:.3g}, {s.seg_iterations} iterations")


class PDEHEAD_PT_boundaries(_StudyPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_boundaries"
    bl_label = "Boundaries"

    def draw(self, context):
        layout = self.layout
        study = self.study(context)
        s = study.settings
        col = layout.column(align=True)
        col.prop(s, "use_tolerance")
        if s.use_tolerance:  # the curves are counted by the tolerance, chosen automatically
            col.prop(s, "tolerance_mm")
            col.prop(s, "max_tolerance_mm")
        else:
            col.prop(s, "patches")
            col.prop(s, "selection")
        col.prop(s, "samples")
        col.prop(s, "align_curves")
        layout.operator("pdehead.extract_boundaries", icon='CURVE_BEZCIRCLE')  # invoked: starts from the settings
        if s.outline_candidates:
            box = layout.box().column(align=True)
            box.label(text=f"Surface from all {abs(s.outline_candidates)} usable outlines:",
                      icon='ERROR' if s.outline_candidates < 0 else 'CHECKMARK')
            box.label(text=f"mean {s.outline_mean_mm:.2f} mm, max {s.outline_max_mm:.2f} mm")
            if s.outline_candidates < 0:
                box.label(text="Tolerance not met with every slice")
        if study.has_stored_boundaries():
            kb = len(study.collection[state.BOUNDARY_KEY]) * 3 / 4 / 1024
            layout.label(text=f"{s.curve_count} curves stored in the .blend ({kb:.0f} kB)", icon='FILE_BLEND')


def draw_detail_map(layout, study) -> None:
    """The CT detail map: off by default; turned on without a current map (never built, or
    the PDE changed since), a *Build CT Detail* button says what is missing (the toggle itself never
    builds: seconds in an update callback would freeze the UI)."""
    s = study.settings
    col = layout.column(align=True)
    col.prop(s, "use_detail_map")
    sub = col.column(align=True)
    sub.enabled = s.use_detail_map
    sub.prop(s, "detail_strength", slider=True)
    sub.prop(s, "detail_resolution")
    if not s.use_detail_map or s.surface_object is None:
        return
    if study.detail_map_current():
        sub.operator("pdehead.build_detail_map", text="Rebuild CT Detail", icon='MOD_DISPLACE')
        return
    box = col.box()
    box.label(text="The PDE changed: rebuild the CT detail" if s.detail_stale
              else "No CT detail map yet (a few seconds)", icon='ERROR' if s.detail_stale else 'INFO')
    row = box.row()
    row.scale_y = 1.4
    row.operator("pdehead.build_detail_map", text="Rebuild CT Detail" if s.detail_stale else "Build CT Detail",
                 icon='MOD_DISPLACE')


class PDEHEAD_PT_surface(_StudyPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_surface"
    bl_label = "Surface"

    def draw(self, context):
        layout = self.layout
        study = self.study(context)
        s = study.settings
        col = layout.column(align=True)
        col.prop(s, "nu")
        col.prop(s, "nv")
        col.prop(s, "caps")
        col = layout.column(align=True)
        col.prop(s, "continuity", text="")
        smooth = s.continuity == "c2"
        row = col.row()
        row.enabled = smooth
        row.prop(s, "dome")
        col = layout.column(align=True)
        col.prop(s, "approximation_auto")
        sub = col.row()
        sub.enabled = smooth and not s.approximation_auto
        sub.prop(s, "approximation", slider=True)
        col.prop(s, "smoothing_auto")
        sub = col.row()
        sub.enabled = not s.smoothing_auto
        sub.prop(s, "smoothing", slider=True)
        col.prop(s, "modes")
        layout.operator("pdehead.reconstruct_surface", icon='MESH_UVSPHERE')
        if s.surface_object is not None:
            layout.label(text=f"{len(s.surface_object.data.vertices)} vertices")
        draw_detail_map(layout, study)


class PDEHEAD_PT_solid(_StudyPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_solid"
    bl_label = "Solid"

    def draw(self, context):
        layout = self.layout
        s = self.study(context).settings
        layout.prop(s, "nw")
        col = layout.column(align=True)
        col.prop(s, "u_range")
        col.prop(s, "v_range")
        col.prop(s, "w_range")
        row = layout.row(align=True)
        row.operator("pdehead.add_cutter", icon='MOD_BOOLEAN')
        row.prop(s, "use_cutter", text="", icon='RESTRICT_SELECT_OFF')
        col = layout.column(align=True)                  # the CT texture
        col.prop(s, "ct_texture_budget")
        col.prop(s, "solid_skin", text="")
        sub = col.row()
        sub.enabled = s.solid_skin == "ct"
        sub.prop(s, "solid_skin_depth")
        layout.operator("pdehead.build_solid", icon='MESH_CUBE')


class PDEHEAD_PT_volume(_StudyPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_volume"
    bl_label = "Volume"

    def draw(self, context):
        layout = self.layout
        s = self.study(context).settings
        row = layout.row()
        row.prop(s, "use_ct_grid")
        sub = row.row()
        sub.enabled = not s.use_ct_grid
        sub.prop(s, "voxel_auto", text="Auto")
        sub = layout.row()
        sub.enabled = not s.use_ct_grid and not s.voxel_auto
        sub.prop(s, "voxel_size")
        col = layout.column(align=True)
        col.prop(s, "low_alpha")
        col.prop(s, "high_alpha")
        col.prop(s, "density")
        col.prop(s, "colour_preset")
        col.prop(s, "alpha_mode")
        layout.operator("pdehead.build_volume", icon='VOLUME_DATA')
        if s.volume_stale:
            layout.label(text="The PDE changed: rebuild the volume", icon='ERROR')


class PDEHEAD_PT_timings(_StudyPanel, bpy.types.Panel):
    bl_idname = "PDEHEAD_PT_timings"
    bl_label = "Timings"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        t = self.study(context).timings
        if not t:
            layout.label(text="No step run yet")
            return
        col = layout.column(align=True)
        for step, seconds in t.items():
            row = col.row()
            row.label(text=step)
            row.label(text=f"{seconds:.3f} s")
        col.separator()
        row = col.row()
        row.label(text="total")
        row.label(text=f"{sum(t.values()):.3f} s")


CLASSES = (PDEHEAD_PT_study, PDEHEAD_PT_segmentation, PDEHEAD_PT_boundaries, PDEHEAD_PT_surface,
           PDEHEAD_PT_solid, PDEHEAD_PT_volume, PDEHEAD_PT_timings)
