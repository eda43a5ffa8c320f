#!/usr/bin/env python3
"""Renders of the automatic craniometric landmarks (issue 22) on the bone (Cycles CPU) into docs/figures/.

    python3 scripts/bench/landmark_figures.py            # a few minutes on 2 cores

* ``landmarks_cthead.png``: CThead's marching-cubes bone with every landmark Find Landmarks placed, front and
  right views: green = ``ok``, yellow = ``uncertain`` (``not_found`` ones have no marker); the hand-placed
  references of ``tests/fixtures/cthead_landmarks.csv`` as small blue markers;
* ``landmarks_phantom.png``: the same on the phantom's facial skeleton, with its analytic landmarks in blue;
* ``landmarks_ge.png``: the clinical GE scan (no mandible: its mandible landmarks are ``not_found``; an orbit
  whose opening runs into another is cut to the other orbit's mirror image), no hand-placed reference.

``--only cthead ge`` renders a subset.

It runs the add-on's operators (registered from this repository, like scripts/pdehead.py).
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT))
OUT = ROOT / "docs" / "figures"
COLOURS = {"ok": (0.1, 0.8, 0.2, 1.0), "uncertain": (0.95, 0.8, 0.05, 1.0), "reference": (0.1, 0.3, 1.0, 1.0)}


def _material(bpy, name, colour):
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = colour
    bsdf.inputs["Emission Color"].default_value = colour
    bsdf.inputs["Emission Strength"].default_value = 1.0
    return mat


def _ball(bpy, coll, name, patient_mm, radius_mm, mat):
    import bmesh
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=2, radius=radius_mm * 0.001)
    bm.to_mesh(me)
    bm.free()
    me.materials.append(mat)
    obj = bpy.data.objects.new(name, me)
    obj.location = tuple(np.asarray(patient_mm, float) * 0.001)
    coll.objects.link(obj)
    return obj


def _figure(bpy, addon, coll, references, out_name, title):
    fs = addon.operators.forensic.study.ForensicStudy.of(addon.operators.study.entity.Study.of(coll))
    render = addon.operators.scene.render
    assert bpy.ops.pdehead.find_landmarks() == {'FINISHED'}
    flags = fs.landmark_flags()
    balls = []
    for name, p in fs.landmarks().items():
        flag = flags.get(name, ("ok", ""))[0]
        balls.append(_ball(bpy, coll, f"auto {name}", p, 2.2, _material(bpy, f"lm {flag}", COLOURS[flag])))
    for name, p in references.items():
        balls.append(_ball(bpy, coll, f"ref {name}", p, 1.3, _material(bpy, "lm reference", COLOURS["reference"])))
    bone_obj = coll["pdehead_bone_object"]
    tmp = Path(tempfile.mkdtemp())
    pics = []
    for view in ("FRONT", "RIGHT"):
        path = tmp / f"{view}.png"
        render.render_objects_png([bone_obj, *balls], path, view=view, resolution=(360, 360), samples=16)
        pics.append(Image.open(path).convert("RGB"))
    fig = Image.new("RGB", (720, 390), (255, 255, 255))
    fig.paste(pics[0], (0, 30))
    fig.paste(pics[1], (360, 30))
    d = ImageDraw.Draw(fig)
    counts = {f: sum(1 for v in flags.values() if v[0] == f) for f in ("ok", "uncertain", "not_found")}
    d.text((8, 8), f"{title}: {counts['ok']} ok (green), {counts['uncertain']} uncertain (yellow), "
                   f"{counts['not_found']} not found; blue = reference", fill=(0, 0, 0))
    OUT.mkdir(parents=True, exist_ok=True)
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(OUT / out_name, optimize=True)
    print("wrote", OUT / out_name)


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=["phantom", "cthead", "ge"], default=["phantom", "cthead", "ge"])
    only = ap.parse_args(argv).only
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fig-"))
    import bpy

    import _common
    import pdehead
    from bench_landmarks import read_fixture
    addon = pdehead.register_addon()

    if "phantom" in only:
        bpy.ops.wm.read_homefile(use_empty=True)
        bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=40, nv=80, nw=4, voxel_size=6.0)
        coll = bpy.context.scene.pdehead.active_study
        bpy.ops.pdehead.build_skull()
        from pdehead_addon.io.phantom import phantom_bone_landmarks
        _figure(bpy, addon, coll, phantom_bone_landmarks(), "landmarks_phantom.png", "Phantom")

    for name in ("cthead", "ge"):
        if name not in only:
            continue
        bpy.ops.wm.read_homefile(use_empty=True)
        bpy.ops.pdehead.import_ct(**_common.addon_import_options(name))
        coll = bpy.context.scene.pdehead.active_study
        bpy.ops.pdehead.segment()
        bpy.ops.pdehead.extract_boundaries(patches=6, samples=128, selection="shape-change")
        bpy.ops.pdehead.reconstruct_surface(nu=40, nv=80)
        bpy.ops.pdehead.build_skull()
        if name == "cthead":
            _figure(bpy, addon, coll, {n: p for n, (p, _) in read_fixture().items()}, "landmarks_cthead.png", "CThead")
        else:
            _figure(bpy, addon, coll, {}, "landmarks_ge.png", "GE (no mandible)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
