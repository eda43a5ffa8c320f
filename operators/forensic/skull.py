"""The forensic skull and the tissue-depth map of a study (the steps behind Build Skull and Tissue Depth).

* **skull** segments the bone from the study's CT and builds the skull as a PDE surface by the
  skin's path (boundary curves -> PDE), plus the marching-cubes bone mesh beside it. The skull's
  boundary curves are stored in the .blend (like the skin's), the meshes are saved.
* **depth** (on demand, never on a slider step) writes the per-vertex depth into the skin surface
  as the POINT attributes ``tissue_depth`` (mm, -1 = no value) and ``tissue_depth_reason`` and
  gives it a colour-ramp material; the ramp is the legend in the panel.

They are methods of :class:`Skull`, a component of :class:`.study.ForensicStudy` (``fs.skull``).
"""
from __future__ import annotations

import base64
import json

import bpy
import numpy as np

from ...pdehead_addon import (
    PDEHeadError,
    check_bone_level,
    defaults as D,
    dumps_boundaries,
    extract_boundaries,
    loads_boundaries,
    max_patches,
    segment_skull,
    skull_mesh,
    solve_pde,
    tissue_depth,
)
from .. import compat, state
from ..outcome import StepOutcome
from ..scene import objects
from .objects import plain_material, set_material

SKULL_BOUNDARY_KEY = "pdehead_skull_boundaries"
DEPTH_STATS_KEY = "pdehead_depth_stats"
SKULL_INFO_KEY = "pdehead_skull_info"
DEPTH_ATTRIBUTE = "tissue_depth"
REASON_ATTRIBUTE = "tissue_depth_reason"
DISPLAY_ATTRIBUTE = "tissue_depth_display"   # shading only (see _display_values)
VALID_ATTRIBUTE = "tissue_depth_valid"
DEPTH_MATERIAL = "PDE Head Tissue Depth"
BONE_MATERIAL = "PDE Head Bone"
#: Depth (mm) at the red end of the colour map.
DEPTH_DISPLAY_MAX_MM = D.DEPTH_DISPLAY_MAX.default


# ------------------------------------------------------------------------------------------ skull
class Skull:
    """The skull and the depth map of a study: a component of its :class:`.study.ForensicStudy` (``fs.skull``);
    its state is in the study's collection, settings and cache."""

    def __init__(self, forensic):
        self.forensic = forensic

    def skull_segmentation(self):
        """The skull segmentation of the study (cached; computed from the CT and the head segmentation)."""
        extra = self.forensic.cache
        cache = self.forensic.study.cache
        if cache.seg is None:
            self.forensic.study.segment()
        s = self.forensic.settings
        level = float(s.bone_level) if s.use_bone_level else None
        if extra.get("skull_seg") is None or extra.get("skull_seg_of") is not cache.seg \
                or extra.get("skull_seg_level") != level:
            # a new head segmentation (or CT, or bone level) makes the skull and everything measured on it stale
            ct = self.forensic.study.ct
            if level is not None and ct.meta.get("format") != "mesh":
                check_bone_level(ct, level)      # a level above the scan's bone: refused before the work
            if extra.get("skull_seg") is not None and extra.get("skull_seg_level") != level:
                self.forensic.collection.pop(SKULL_BOUNDARY_KEY, None)      # the stored envelope was of the old level
            extra.update(skull_seg=segment_skull(self.forensic.study.ct, cache.seg, bone_level=level),
                         skull_seg_of=cache.seg, skull_seg_level=level, bone_mesh=None, skull_mesh=None, depth=None)
            for w in extra["skull_seg"].meta.get("warnings", []):
                if w not in s.warnings:
                    s.warnings = "; ".join(filter(None, [s.warnings, w]))
        return extra["skull_seg"]

    def _envelope_head(self):
        """The PDE skull envelope (boundary set, solved head, t) from the skull segmentation, by the skin's path."""
        s = self.forensic.settings
        sk = self.skull_segmentation()
        limit = max_patches(sk)
        if limit < 1:
            raise PDEHeadError(f"study '{self.forensic.name}': the skull has fewer than 4 usable outlines; "
                               "no PDE skull envelope")
        patches = min(int(s.patches), limit)
        bset = extract_boundaries(sk, patches=patches, samples=int(s.samples), selection=s.selection)
        return bset, solve_pde(bset), patches

    def step_skull(self, nu: int = D.SKULL_NU.default, nv: int = D.SKULL_NV.default,
                   bone: bool = D.BONE_MESH.default, bone_step: int = D.BONE_STEP.default) -> StepOutcome:
        """The bone skull (smoothed marching cubes of the bone: what skull.<fmt> is) and the PDE skull envelope
        (``nu`` x ``nv`` samples; 0: the skin's); returns the objects built (the envelope, then the bone mesh),
        the segmentation's warnings, the seconds and what the skull info records (``values``: bone level,
        patches, parts, bone volume, ...)."""
        coll = self.forensic.collection
        extra = self.forensic.cache
        nu, nv = int(nu) or int(self.forensic.settings.nu), int(nv) or int(self.forensic.settings.nv)
        with state.Timer() as t:
            sk = self.skull_segmentation()
            bset, head, patches = self._envelope_head()
            mesh = head.surface(int(nu), int(nv), caps=True)
        coll[SKULL_BOUNDARY_KEY] = base64.b64encode(dumps_boundaries(bset)).decode("ascii")
        extra.update(skull_head=head, skull_mesh=mesh, depth=None)
        obj = objects.build_mesh_object(mesh, coll, f"{coll.name} Skull",
                                        obj=self.forensic.linked_object("pdehead_skull_object"))
        obj["pdehead_kind"] = "skull"
        set_material(obj, plain_material(BONE_MATERIAL, (0.85, 0.82, 0.72, 1.0)))
        coll["pdehead_skull_object"] = obj
        info = dict(bone_level=sk.bone_level, calibrated=sk.meta["calibrated"],
                    source=sk.meta["histogram"].get("source"), patches=patches,
                    components=sk.meta["kept_components"], bone_cm3=sk.meta["bone_mm3"] / 1000.0,
                    metal_voxels=sk.meta["metal_voxels"])
        for key in ("bone_level_stored", "units", "warnings", "mandible", "has_skin", "soft_tissue",
                    "skull_mesh_file"):
            if key in sk.meta:
                info[key] = sk.meta[key]
        if bone:
            bmesh = skull_mesh(sk, step=int(bone_step))
            extra["bone_mesh"] = bmesh
            bobj = objects.build_mesh_object(bmesh, coll, f"{coll.name} Bone",
                                             obj=self.forensic.linked_object("pdehead_bone_object"), smooth=True)
            bobj["pdehead_kind"] = "bone_mesh"
            set_material(bobj, plain_material(BONE_MATERIAL, (0.85, 0.82, 0.72, 1.0)))
            coll["pdehead_bone_object"] = bobj
            info["bone_triangles"] = len(bmesh.triangles)
        coll[SKULL_INFO_KEY] = json.dumps(info)
        self.forensic.study.record_timing("skull", t.seconds)
        built = (obj, bobj) if bone else (obj,)
        return StepOutcome("skull", objects=built, warnings=tuple(str(w) for w in sk.meta.get("warnings", ())),
                           seconds=t.seconds, values=info)

    def skull_info(self) -> dict:
        """What the last Build Skull recorded (bone level, parts, volume, mandible; {} before it)."""
        return json.loads(self.forensic.collection.get(SKULL_INFO_KEY, "{}") or "{}")

    def skull_engine_mesh(self, target: str = D.DEPTH_TARGET.default):
        """The skull as an engine Mesh (patient mm): the bone skull, or the PDE skull envelope (built when
        missing, rebuilt from the stored curves after reopening)."""
        extra = self.forensic.cache
        if target == "BONE":
            if extra.get("bone_mesh") is None:
                extra["bone_mesh"] = skull_mesh(self.skull_segmentation())
            return extra["bone_mesh"]
        if extra.get("skull_mesh") is None:
            s = self.forensic.settings
            text = self.forensic.collection.get(SKULL_BOUNDARY_KEY)
            if text:
                head = solve_pde(loads_boundaries(base64.b64decode(text)))
            else:
                bset, head, _ = self._envelope_head()
                self.forensic.collection[SKULL_BOUNDARY_KEY] = base64.b64encode(dumps_boundaries(bset)).decode("ascii")
            extra["skull_head"], extra["skull_mesh"] = head, head.surface(int(s.nu), int(s.nv), caps=True)
        return extra["skull_mesh"]

    def skin_engine_mesh(self):
        """The PDE skin as an engine Mesh with the surface object's vertex order (same nu, nv, caps)."""
        s = self.forensic.settings
        return self.forensic.study.head.surface(int(s.nu), int(s.nv), caps=bool(s.caps))

    # -------------------------------------------------------------------------------------- depth
    def step_depth(self, target: str = D.DEPTH_TARGET.default,
                   max_depth_mm: float = D.MAX_DEPTH.default) -> StepOutcome:
        """Tissue depth of the skin surface against the skull, stored on the surface object; returns the surface
        object, the seconds and the statistics (``values``: vertices, measured, median, ..., target,
        max_depth_mm)."""
        s = self.forensic.settings
        if s.surface_object is None:
            self.forensic.study.surface()
        obj = s.surface_object
        skin = self.skin_engine_mesh()
        if len(skin.vertices) != len(obj.data.vertices):  # the surface was edited or built otherwise
            self.forensic.study.surface()
            obj = s.surface_object
        with state.Timer() as t:
            res = tissue_depth(skin, self.skull_engine_mesh(target), envelope=self.skull_segmentation(),
                               max_depth_mm=float(max_depth_mm))
        me = obj.data
        valid = np.isfinite(res.depth)
        for name, kind, values in ((DEPTH_ATTRIBUTE, 'FLOAT', np.where(valid, res.depth, -1.0)),
                                   (DISPLAY_ATTRIBUTE, 'FLOAT', _display_values(skin, res.depth)),
                                   (VALID_ATTRIBUTE, 'FLOAT', valid.astype(np.float32)),
                                   (REASON_ATTRIBUTE, 'INT', res.reason.astype(np.int32))):
            if name in me.attributes:
                me.attributes.remove(me.attributes[name])
            attr = me.attributes.new(name, kind, 'POINT')
            attr.data.foreach_set("value", np.ascontiguousarray(values, np.float32 if kind == 'FLOAT' else np.int32))
        set_material(obj, depth_material())
        stats = res.statistics()
        stats.update(target=target, max_depth_mm=float(max_depth_mm), seconds=round(t.seconds, 2))
        self.forensic.collection[DEPTH_STATS_KEY] = json.dumps(stats)
        self.forensic.cache["depth"] = res
        self.forensic.study.record_timing("depth", t.seconds)
        return StepOutcome("depth", objects=(obj,), seconds=t.seconds, values=stats)

    def depth_stats(self) -> dict:
        """The statistics of the last Tissue Depth ({} before it)."""
        return json.loads(self.forensic.collection.get(DEPTH_STATS_KEY, "{}") or "{}")


# ------------------------------------------------------------------------------------------ depth map
def _display_values(mesh, depth: np.ndarray, passes: int = 4) -> np.ndarray:
    """Depth for shading: vertices without a value take the mean of their measured neighbours.

    Shading interpolates between vertices; a stored -1 next to a measured 10 mm would paint every
    value in between (a blue seam around each grey patch). The grey itself comes from
    ``tissue_depth_valid``, so these fill-in values are never shown as depths.
    """
    out = np.where(np.isfinite(depth), depth, np.nan).astype(np.float64)
    e = mesh.edges()
    for _ in range(passes):
        known = np.isfinite(out)
        if known.all():
            break
        acc = np.zeros(len(out))
        cnt = np.zeros(len(out))
        for a, b in ((e[:, 0], e[:, 1]), (e[:, 1], e[:, 0])):
            k = known[b] & ~known[a]
            np.add.at(acc, a[k], out[b[k]])
            np.add.at(cnt, a[k], 1.0)
        fill = cnt > 0
        out[fill] = acc[fill] / cnt[fill]
    return np.nan_to_num(out, nan=0.0).astype(np.float32)


def depth_material():
    """Attribute ``tissue_depth_display`` -> Map Range (0..DEPTH_DISPLAY_MAX_MM) -> Color Ramp; grey where
    ``tissue_depth_valid`` < 0.5 (no value)."""
    mat = bpy.data.materials.get(DEPTH_MATERIAL)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(DEPTH_MATERIAL)
    compat.node_tree(mat)  # nodes on where Blender < 5.0 starts without
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes.get("Principled BSDF")
    bsdf.inputs["Roughness"].default_value = 0.6
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = DISPLAY_ATTRIBUTE
    attr.attribute_type = 'GEOMETRY'
    attr.location = (-900, 200)
    valid_attr = nodes.new("ShaderNodeAttribute")
    valid_attr.attribute_name = VALID_ATTRIBUTE
    valid_attr.attribute_type = 'GEOMETRY'
    valid_attr.location = (-900, -50)
    rng = nodes.new("ShaderNodeMapRange")
    rng.name = rng.label = "Depth range"
    rng.inputs["From Min"].default_value = 0.0
    rng.inputs["From Max"].default_value = DEPTH_DISPLAY_MAX_MM
    rng.location = (-700, 200)
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.name = ramp.label = "Depth legend"
    ramp.location = (-500, 200)
    els = ramp.color_ramp.elements
    els[0].position, els[0].color = 0.0, (0.05, 0.15, 0.85, 1.0)     # thin: blue
    els[1].position, els[1].color = 1.0, (0.85, 0.05, 0.05, 1.0)     # thick: red
    for pos, col in ((0.25, (0.0, 0.7, 0.9, 1.0)), (0.5, (0.1, 0.8, 0.2, 1.0)), (0.75, (0.95, 0.85, 0.1, 1.0))):
        e = els.new(pos)
        e.color = col
    valid = nodes.new("ShaderNodeMath")
    valid.operation = 'GREATER_THAN'
    valid.inputs[1].default_value = 0.5     # grey where the interpolated validity is below one half
    valid.location = (-500, -50)
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = 'RGBA'
    mix.location = (-250, 100)
    mix.inputs["A"].default_value = (0.55, 0.55, 0.55, 1.0)         # no value: grey
    links.new(attr.outputs["Fac"], rng.inputs["Value"])
    links.new(rng.outputs["Result"], ramp.inputs["Fac"])
    links.new(valid_attr.outputs["Fac"], valid.inputs[0])
    links.new(valid.outputs["Value"], mix.inputs["Factor"])
    links.new(ramp.outputs["Color"], mix.inputs["B"])
    links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    mat.diffuse_color = (0.3, 0.7, 0.3, 1.0)
    return mat
