"""Renders of the CT detail as geometry: CThead's face up close, marching cubes of the mask beside the PDE
surface in Blender with its CT detail displacement at strength 0, 0.5 and 1 (the add-on's modifiers:
Catmull-Clark x2, then Displace by the map in UVs), front, three-quarter and from below; and the exported
skin (the print mesh at strength 1) from the front. Cycles CPU, into ``docs/figures/detail_face.png``.

    python3 scripts/bench/detail_figures.py [--size 384] [--samples 16]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[2]
for p in (str(ROOT), str(ROOT / "scripts"), str(ROOT / "scripts" / "bench")):
    if p not in sys.path:
        sys.path.insert(0, p)

import _common  # noqa: E402
import bench_smooth  # noqa: E402
import pdehead_addon as E  # noqa: E402

#: Views the add-on does not name, as (direction the camera looks along, world up): the nostrils are seen
#: from below and in front (the camera looks up and back).
EXTRA_VIEWS = {"BELOW_FRONT": ((0.0, 0.75, 0.66), (0.0, 0.0, 1.0))}
from up_close_figures import sheet  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    ap.add_argument("--views", default="FRONT,THREE_QUARTER")
    ap.add_argument("--zoom", action="store_true",
                    help="detail_face_zoom.png: the eyes and nose only (35 mm either side, 25 mm under to 45 mm "
                         "over the nose tip), front and from below-front (the nostrils)")
    ap.add_argument("--eyes", action="store_true",
                    help="detail_face_eyes.png: the closed eyes only (50 mm either side, 10 to 55 mm over the nose "
                         "tip), front and three-quarter, marching cubes beside strengths 0, 0.5 and 1")
    args = ap.parse_args(argv)
    bl = _common.blender()
    bpy, objects, render, detail = bl["bpy"], bl["objects"], bl["render"], bl["detail_map"]
    from pdehead_addon import defaults as D
    bpy.ops.wm.read_homefile(use_empty=True)
    seg = bench_smooth.load("cthead")
    head = E.solve_pde(E.extract_boundaries(seg, patches=D.PATCHES.default, selection=bench_smooth.SELECTION))
    mc = _common.marching_cubes_mesh(seg.mask, seg.ct)
    dmap = E.ct_detail_map(head, seg.mask, seg.ct)
    tip = np.asarray(bench_smooth.visible_face(seg, head.surface(D.NU.default, D.NV.default, caps=True),
                                               (mc.vertices, mc.triangles))["pronasale"], float)
    coll = objects.study_collection("detail figures")
    tiles = [("marching cubes", objects.build_mesh_object(mc, coll, "mc", smooth=False), None)]
    for s in (0.0, 0.5, 1.0):
        obj = objects.build_mesh_object(head.surface(D.NU.default, D.NV.default, caps=True), coll, f"detail {s:g}",
                                        smooth=True)
        detail.set_detail_image(obj, dmap.height, dmap.meta["max_mm"])
        detail.set_detail_shading(obj, s, True)
        tiles.append((f"PDE + CT detail {s:g} (Blender)", obj, s))
    rows, nv = E.print_resolution(head)
    nu = len(rows)
    printed = E.print_mesh(head, dmap.height, 1.0)             # what Export for Printing writes
    tiles.append((f"skin.stl {nu}x{nv} strength 1", objects.build_mesh_object(printed, coll, "print", smooth=False),
                  None))
    for _, obj, _ in tiles:
        obj.data.materials.append(objects.ensure_skin_material())
    lo = 0.001 * (tip + np.array([-60.0, 0.0, -70.0]))
    hi = 0.001 * (tip + np.array([60.0, 60.0, 60.0]))
    if args.zoom:
        # the nostrils, seen from below and in front (EXTRA_VIEWS)
        lo = 0.001 * (tip + np.array([-35.0, 0.0, -25.0]))
        hi = 0.001 * (tip + np.array([35.0, 40.0, 45.0]))
        tiles = [tiles[0], tiles[1], tiles[3]]
        args.views = "FRONT,BELOW_FRONT"
    if args.eyes:
        # the closed upper lids' line, seen from the front and three-quarter
        lo = 0.001 * (tip + np.array([-50.0, 0.0, 10.0]))
        hi = 0.001 * (tip + np.array([50.0, 50.0, 55.0]))
        tiles = tiles[:4]
    tmp = args.out / ".tile_detail.png"
    rows = []
    for view in args.views.split(","):
        row = []
        for label, obj, _ in tiles:
            render.render_objects_png([obj], tmp, view=EXTRA_VIEWS.get(view, view), resolution=(args.size, args.size),
                                      samples=args.samples, bounds=(lo, hi))
            with Image.open(tmp) as im:
                im = im.convert("RGB").copy()
            ImageDraw.Draw(im).text((8, 6), f"CThead {label}", fill=(235, 235, 235))
            row.append(im)
        rows.append(row)
    tmp.unlink(missing_ok=True)
    sheet(rows, args.out / ("detail_face_zoom.png" if args.zoom else "detail_face_eyes.png" if args.eyes
                             else "detail_face.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
