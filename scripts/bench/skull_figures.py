#!/usr/bin/env python3
"""Renders of the bone skull (issue 22) on CThead and GE (Cycles CPU) into docs/figures/forensic_bone_skull.png.

    python3 scripts/bench/skull_figures.py            # a few minutes on 2 shared cores

Top row CThead, bottom row GE: the bone skull (``skull.stl``: smoothed marching cubes of the bone mask)
from the front and three-quarter, and the PDE skull envelope (``skull_envelope.stl``) from the front:
the orbits, the nasal aperture and the zygomatic arches are open in the bone, closed over in the envelope.
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
OUT = ROOT / "docs" / "figures"
SIZE = 260


def main() -> int:
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fig-"))
    import bpy

    import _common
    import pdehead
    addon = pdehead.register_addon()
    render = addon.operators.scene.render
    tmp = Path(tempfile.mkdtemp())
    rows = []
    for name in ("CThead", "GE"):
        bpy.ops.wm.read_homefile(use_empty=True)
        if name == "CThead":
            bpy.ops.pdehead.import_ct(**_common.addon_import_options("cthead"))
        else:
            bpy.ops.pdehead.import_ct(**_common.addon_import_options("ge"))
        coll = bpy.context.scene.pdehead.active_study
        bpy.ops.pdehead.segment()
        bpy.ops.pdehead.extract_boundaries(patches=8, samples=256)
        bpy.ops.pdehead.reconstruct_surface(nu=120, nv=240)
        bpy.ops.pdehead.build_skull()
        bone, envelope = coll["pdehead_bone_object"], coll["pdehead_skull_object"]
        pics = []
        for obj, view in ((bone, "FRONT"), (bone, "THREE_QUARTER"), (envelope, "FRONT")):
            path = tmp / f"{name}_{obj.name}_{view}.png"
            render.render_objects_png([obj], path, view=view, resolution=(SIZE, SIZE), samples=16)
            pics.append(Image.open(path).convert("RGB"))
        row = Image.new("RGB", (3 * SIZE, SIZE + 18), (255, 255, 255))
        draw = ImageDraw.Draw(row)
        for i, (pic, label) in enumerate(zip(pics, ("bone skull (skull.stl), front", "bone skull, three-quarter",
                                                    "PDE envelope (skull_envelope.stl)"))):
            row.paste(pic, (i * SIZE, 18))
            draw.text((i * SIZE + 6, 3), f"{name}: {label}", fill=(0, 0, 0))
        rows.append(row)
    fig = Image.new("RGB", (3 * SIZE, len(rows) * (SIZE + 18)), (255, 255, 255))
    for i, row in enumerate(rows):
        fig.paste(row, (0, i * (SIZE + 18)))
    OUT.mkdir(parents=True, exist_ok=True)
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
        OUT / "forensic_bone_skull.png", optimize=True)
    print(f"wrote {OUT / 'forensic_bone_skull.png'}")
    return 0


if __name__ == "__main__":
    import argparse  # no options: --help prints what the script renders, and renders nothing
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    sys.exit(main())
