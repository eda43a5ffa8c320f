"""Renders of the smooth PDE head (issue 8): the default C2 surface, the paper's patches and marching cubes.

For CThead (t = 10), the GE tilted series (t = 8) and the phantom (t = 10), with the add-on's
boundary pipeline, each of the three surfaces from the front, the patient's right and
three-quarter, Cycles CPU at 512 px per tile, into ``docs/figures/smooth_<data>.png``
(rows: C2 default, paper patches, marching cubes of the segmentation mask).

    python3 scripts/bench/smooth_figures.py [--size 512] [--samples 16] [--only cthead]
    python3 scripts/bench/smooth_figures.py --selections 4 --only cthead   # issue 14: uniform / shape-change /
                                      # auto rows at t = 4 into docs/figures/selection_<data>_t4.png
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[2]
for p in (str(ROOT), str(ROOT / "scripts")):
    if p not in sys.path:
        sys.path.insert(0, p)

import _common  # noqa: E402  (the dev-shim loader of the add-on's Blender modules)
import bench_smooth  # noqa: E402
import pdehead_addon as E  # noqa: E402

CASES = {"cthead": 10, "ge": 8, "phantom": 10}
VIEWS = ("FRONT", "RIGHT", "THREE_QUARTER")


def surfaces(seg, t: int) -> list[tuple[str, E.Mesh]]:
    bset = E.extract_boundaries(seg, patches=t, selection=bench_smooth.SELECTION)
    n = 20 * t + 1
    c2 = E.solve_pde(bset).surface(n, 360, caps=True)
    paper = E.solve_pde(bset, continuity="paper").surface(n, 360, caps=True)
    mc = _common.marching_cubes_mesh(seg.mask, seg.ct)
    return [(f"C2 default (t={t})", c2), (f"paper patches (t={t})", paper), ("marching cubes (all slices)", mc)]


def selection_surfaces(seg, t: int) -> list[tuple[str, E.Mesh]]:
    """The default C2 surface through the curves of each slice selection (issue 14)."""
    rows = []
    for selection in ("uniform", "shape-change", "auto"):
        bset = E.extract_boundaries(seg, patches=t, selection=selection)
        rows.append((f"{selection} (t={t}, {bset.curves.shape[0]} curves)",
                     E.solve_pde(bset).surface(20 * t + 1, 360, caps=True)))
    return rows


def render_case(name: str, t: int, size: int, samples: int, out: Path, selections: bool = False) -> Path:
    bl = _common.blender()
    bpy, objects, render = bl["bpy"], bl["objects"], bl["render"]
    bpy.ops.wm.read_homefile(use_empty=True)
    seg = bench_smooth.load(name)
    coll = objects.study_collection(f"figure {name}")
    built = []
    for label, mesh in (selection_surfaces if selections else surfaces)(seg, t):
        obj = objects.build_mesh_object(mesh, coll, label, smooth=True)
        obj.data.materials.append(objects.ensure_skin_material())
        built.append((label, obj))
    bounds = render.world_bounds([o for _, o in built])
    rows = []
    tmp = out.parent / f".tile_{name}.png"
    for label, obj in built:
        tiles = []
        for view in VIEWS:
            render.render_objects_png([obj], tmp, view=view, resolution=(size, size), samples=samples,
                                      bounds=bounds)
            with Image.open(tmp) as im:
                tile = im.convert("RGB").copy()
            ImageDraw.Draw(tile).text((8, 6), f"{label} - {view.lower().replace('_', '-')}", fill=(235, 235, 235))
            tiles.append(tile)
        rows.append(tiles)
    tmp.unlink(missing_ok=True)
    sheet = Image.new("RGB", (size * len(VIEWS), size * len(rows)))
    for i, tiles in enumerate(rows):
        for j, tile in enumerate(tiles):
            sheet.paste(tile, (j * size, i * size))
    path = out / (f"selection_{name}_t{t}.png" if selections else f"smooth_{name}.png")
    # 64 colours without dithering: the shading stays smooth and the sheet under 1 MB
    sheet.quantize(colors=64, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, optimize=True)
    print(path, flush=True)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--only", choices=sorted(CASES), action="append")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    ap.add_argument("--selections", type=int, metavar="T",
                    help="render uniform / shape-change / auto rows at this t instead")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.only or CASES:
        render_case(name, args.selections or CASES[name], args.size, args.samples, args.out,
                    selections=bool(args.selections))
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())
