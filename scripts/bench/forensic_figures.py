#!/usr/bin/env python3
"""Renders of the forensic toolkit on CThead (Cycles CPU) into docs/figures/.

    python3 scripts/bench/forensic_figures.py            # about a minute on 2 cores

* ``forensic_depth_map.png``: the PDE skin (t = 10, 120 x 240) coloured by the soft-tissue depth to
  the marching-cubes bone (0 mm blue .. 25 mm red, grey = no value), front and right views, with a
  colour bar;
* ``forensic_pegs.png``: the bone mesh with marker pegs at landmarks placed from the bone's
  geometry (front-most midline points at given heights, lateral points of the zygomatic arches and
  the gonia); the peg lengths are the depths measured at those landmarks on this cadaver (exported
  with Export Landmark Depths and imported again as a depth table), so each peg should end at the
  skin, shown as a transparent shell.

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
OUT = ROOT / "docs" / "figures"


def colour_bar(height: int, width: int, max_mm: float, ramp) -> Image.Image:
    bar = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(bar)
    pos = np.array([p for p, _ in ramp])
    cols = np.array([c for _, c in ramp])
    top, bottom = 20, height - 40
    for y in range(top, bottom):
        t = 1.0 - (y - top) / (bottom - top)
        c = np.array([np.interp(t, pos, cols[:, k]) for k in range(3)]) ** (1 / 2.2)  # linear -> sRGB-ish
        draw.line([(8, y), (28, y)], fill=tuple(int(255 * v) for v in c))
    for mm in (0, max_mm / 2, max_mm):
        y = bottom - (bottom - top) * mm / max_mm
        draw.text((32, y - 6), f"{mm:g} mm", fill=(0, 0, 0))
    draw.rectangle([(8, height - 30), (28, height - 16)], fill=(140, 140, 140))
    draw.text((32, height - 30), "none", fill=(0, 0, 0))
    return bar


def main() -> int:
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fig-"))
    import bpy

    import _common
    import pdehead
    addon = pdehead.register_addon()
    skull = addon.operators.forensic.skull
    render = addon.operators.scene.render
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.pdehead.import_ct(**_common.addon_import_options("cthead"))
    coll = bpy.context.scene.pdehead.active_study
    bpy.ops.pdehead.segment()
    bpy.ops.pdehead.extract_boundaries(patches=10, samples=256, selection="shape-change")
    bpy.ops.pdehead.reconstruct_surface(nu=120, nv=240)
    bpy.ops.pdehead.build_skull()
    bpy.ops.pdehead.tissue_depth(target='BONE')
    fs = addon.operators.forensic.study.ForensicStudy.of(addon.operators.study.entity.Study.of(coll))
    s = coll.pdehead
    skin = s.surface_object
    OUT.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp())
    views = []
    for view in ("FRONT", "RIGHT"):
        path = tmp / f"depth_{view}.png"
        render.render_objects_png([skin], path, view=view, resolution=(300, 300), samples=16)
        views.append(Image.open(path).convert("RGB"))
    mat = bpy.data.materials[skull.DEPTH_MATERIAL]
    els = mat.node_tree.nodes["Depth legend"].color_ramp.elements
    ramp = [(e.position, tuple(e.color)[:3]) for e in els]
    bar = colour_bar(300, 80, skull.DEPTH_DISPLAY_MAX_MM, ramp)
    fig = Image.new("RGB", (680, 300), (255, 255, 255))
    fig.paste(views[0], (0, 0))
    fig.paste(views[1], (300, 0))
    fig.paste(bar, (600, 0))
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
        OUT / "forensic_depth_map.png", optimize=True)

    # landmarks from the bone mesh's geometry (patient mm), then pegs with the measured depths
    bone = fs.skull.skull_engine_mesh("BONE")
    v = bone.vertices
    skin_v = fs.skull.skin_engine_mesh().vertices
    xc = 0.5 * (skin_v[:, 0].min() + skin_v[:, 0].max())
    tip_z = skin_v[np.argmin(skin_v[:, 1]), 2]

    def front(z, x, tol=3.0):
        sel = (np.abs(v[:, 2] - z) < tol) & (np.abs(v[:, 0] - x) < tol)
        return v[sel][np.argmin(v[sel, 1])]

    tip_y = skin_v[:, 1].min()

    def side(z, sign, depth_mm, tol=3.0):  # most lateral bone point at height z, within depth_mm of the face
        sel = (np.abs(v[:, 2] - z) < tol) & (v[:, 1] < tip_y + depth_mm)
        sel &= (v[:, 0] - xc) * sign > 0
        return v[sel][np.argmax(np.abs(v[sel, 0] - xc))]

    points = {"Glabella": front(tip_z + 55, xc), "Nasion": front(tip_z + 40, xc), "Mid-philtrum": front(tip_z - 15, xc),
              "Pogonion": front(tip_z - 60, xc), "Frontal eminence L": front(tip_z + 75, xc + 25),
              "Frontal eminence R": front(tip_z + 75, xc - 25), "Zygomatic arch L": side(tip_z + 15, 1, 75),
              "Zygomatic arch R": side(tip_z + 15, -1, 75), "Gonion L": side(tip_z - 40, 1, 110),
              "Gonion R": side(tip_z - 40, -1, 110)}
    from mathutils import Vector
    for name, p in points.items():
        bpy.ops.pdehead.place_landmark(name=name, location=Vector(p * 0.001), use_location=True)
    csv_path = tmp / "measured.csv"
    bpy.ops.pdehead.export_landmark_depths(filepath=str(csv_path))
    rows = [r.split(",") for r in csv_path.read_text().splitlines() if not r.startswith("#")][1:]
    table = tmp / "table.csv"
    table.write_text("landmark,depth_mm\n" + "".join(f"{r[0]},{r[4]}\n" for r in rows if r[4]))
    print(csv_path.read_text())
    bpy.ops.pdehead.import_depth_table(filepath=str(table))
    pegs = [o for o in coll.all_objects if "pdehead_peg" in o]
    bone_obj = coll["pdehead_bone_object"]
    shell = skin.copy()
    shell.data = skin.data.copy()
    coll.objects.link(shell)
    glass = bpy.data.materials.new("Skin shell")
    if glass.node_tree is None:
        glass.use_nodes = True
    bsdf = glass.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.8, 0.6, 0.5, 1.0)
    bsdf.inputs["Alpha"].default_value = 0.18
    shell.data.materials[0] = glass
    pics = []
    for view in ("THREE_QUARTER", "RIGHT"):
        path = tmp / f"pegs_{view}.png"
        render.render_objects_png([bone_obj, shell, *pegs], path, view=view, resolution=(340, 340), samples=16)
        pics.append(Image.open(path).convert("RGB"))
    fig = Image.new("RGB", (680, 340), (255, 255, 255))
    fig.paste(pics[0], (0, 0))
    fig.paste(pics[1], (340, 0))
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
        OUT / "forensic_pegs.png", optimize=True)
    print("wrote", OUT / "forensic_depth_map.png", OUT / "forensic_pegs.png")
    return 0


if __name__ == "__main__":
    import argparse  # no options: --help prints what the script renders, and renders nothing
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    sys.exit(main())
