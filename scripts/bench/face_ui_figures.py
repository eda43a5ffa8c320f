#!/usr/bin/env python3
"""Renders of Face from Skull in Blender (Cycles CPU) into docs/figures/face_ui_<dataset>.png.

    python3 scripts/bench/face_ui_figures.py                   # CThead, a few minutes on 2 cores
    python3 scripts/bench/face_ui_figures.py --dataset phantom
    python3 scripts/bench/face_ui_figures.py --dataset ge --out-dir /tmp/figures    # not into docs/

Runs the add-on's operators as a user clicks them (registered from this repository, like
scripts/pdehead.py): the CT imported, Build Skull, Find Landmarks, Build Face. Four pictures:
the face from the front and the right, the bone skull with its pegs inside the face (shown as a
transparent shell), and the face after the pogonion peg (or the first peg) was dragged 8 mm
forward the way G drags it -- the handler re-solves the same face object. Every picture carries the
label the face object carries: "approximation -- not an identification".
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
OUT = ROOT / "docs" / "figures"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dataset", default="cthead", choices=["cthead", "ge", "phantom"])
    p.add_argument("--size", type=int, default=300)
    p.add_argument("--samples", type=int, default=16)
    p.add_argument("--out-dir", type=Path, default=OUT, help="where face_ui_<dataset>.png goes; default docs/figures")
    args = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fig-"))
    import bpy
    from mathutils import Vector

    import _common
    import pdehead
    addon = pdehead.register_addon()
    face = addon.operators.forensic.face
    render = addon.operators.scene.render
    bpy.ops.wm.read_homefile(use_empty=True)
    if args.dataset == "phantom":
        bpy.ops.pdehead.run_pipeline(source='PHANTOM', build_volume=False)
    else:
        bpy.ops.pdehead.import_ct(**_common.addon_import_options(args.dataset))
    coll = bpy.context.scene.pdehead.active_study
    for op in ("build_skull", "find_landmarks", "build_face"):
        assert getattr(bpy.ops.pdehead, op)() == {'FINISHED'}, op
    fs = addon.operators.forensic.study.ForensicStudy.of(addon.operators.study.entity.Study.of(coll))
    obj = fs.face.face_object()
    bone = coll["pdehead_bone_object"]
    names = fs.face.face_options()["pegs"]
    pegs = fs.face.peg_objects(names)
    for o in list(coll.all_objects):                # only what the pictures show (a list: hide_render
        # rebuilds the collection's object cache while it would be iterated)
        if o not in (obj, bone, *pegs.values()):
            o.hide_render = True
    tmp = Path(tempfile.mkdtemp())
    size = args.size
    pics = []
    bounds = render.world_bounds([obj])
    for view in ("FRONT", "RIGHT"):
        path = tmp / f"face_{view}.png"
        render.render_objects_png([obj], path, view=view, resolution=(size, size), samples=args.samples,
                                  bounds=bounds, isolate=True)
        pics.append((Image.open(path).convert("RGB"), f"face, {view.lower()}"))
    # the pegs on the bone inside the face, shown as a shell
    mat = obj.data.materials[0]
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    alpha = bsdf.inputs["Alpha"].default_value
    bsdf.inputs["Alpha"].default_value = 0.25
    path = tmp / "pegs.png"
    render.render_objects_png([bone, obj, *pegs.values()], path, view="THREE_QUARTER", resolution=(size, size),
                              samples=args.samples, bounds=bounds)
    pics.append((Image.open(path).convert("RGB"), f"bone and {len(pegs)} pegs"))
    bsdf.inputs["Alpha"].default_value = alpha
    # drag: pogonion 15 mm forward (patient -y), as G does; the face follows
    name = "Pogonion" if "Pogonion" in pegs else names[0]
    pegs[name].matrix_world.translation += Vector((0.0, -0.015, 0.0))
    bpy.context.view_layer.update()
    path = tmp / "dragged.png"
    render.render_objects_png([obj], path, view="RIGHT", resolution=(size, size), samples=args.samples,
                              bounds=bounds, isolate=True)
    pics.append((Image.open(path).convert("RGB"), f"{name} peg dragged 15 mm forward"))
    label = str(obj[face.LABEL_PROP]).replace("\u2014", "-")      # the default PIL font has no em dash
    fig = Image.new("RGB", (size * len(pics), size + 44), (255, 255, 255))
    draw = ImageDraw.Draw(fig)
    for i, (im, caption) in enumerate(pics):
        fig.paste(im, (i * size, 0))
        draw.text((i * size + 6, size + 4), caption, fill=(0, 0, 0))
    draw.text((6, size + 24), f"{args.dataset}: {label} (PDE Head, Face from Skull, "
                              f"{len(names)} pegs, T-Table 2023)", fill=(160, 0, 0))
    args.out_dir.mkdir(parents=True, exist_ok=True)
    out = args.out_dir / f"face_ui_{args.dataset}.png"
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(out, optimize=True)
    print("wrote", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
