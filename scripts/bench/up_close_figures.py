"""Renders for issue 21 ("Up close"): the crown's pole, the neck's cap and the surface's UVs, before and after.

CThead (t = 10) and the GE tilted series (t = 8) at the add-on's defaults (automatic slices, C2
surface, nu x nv = 120 x 240, caps), Cycles CPU, into ``docs/figures/up_close_*.png``:

* ``up_close_crown.png``: seen from above; before (the dome without the fade: radial ridges into the
  pole) and after;
* ``up_close_neck.png``: seen from below; before (a fan of long triangles to the spine point) and after
  (a flat disc triangulated ring by ring);
* ``up_close_uv.png``: a UV grid texture on CThead, front and three-quarter; before (mirrored UVs (u, v),
  caps of zero UV area) and after (the tube, dome and cap islands).

"Before" is ``bench_smooth.legacy_surface``: the same head meshed as before issue 21.

* ``up_close_face.png`` (``--face``, only this figure): CThead's face, front and three-quarter, close up:
  marching cubes of the mask, the surface at t = 10 with the u smoothing of one slice step (the defaults
  before issue 21's last change) and at the add-on's defaults (t = 15, half a slice step); the
  visible-face score on each tile; and the defaults' surface shaded with its CT detail map (the same
  geometry, the scan's eyelids, lips and nose wings as bump: ``operators/scene/detail_map.py``).
* ``up_close_cut.png`` (``--cut``, only this figure): CThead's solid cut at the mid-sagittal plane
  (v from 0 to 180 degrees: the patient's right half), seen from its left at the add-on's defaults (skin
  outside, the cut faces from the CT at <= 1 voxel a texel), beside the CT resampled on the plane
  x = the spine's mean x, same window, and the solid as before issue 21 (one 128-pixel tile a face).

* ``up_close_crown41.png`` (``--crown``, only this figure; issue 41 item 2): CThead's crown at the add-on's
  defaults (t = 15, a 400 x 800 surface) from above and at a grazing angle: without the crown's low-pass
  (``pde_spline.crown_low_pass``), with it, and marching cubes of the mask smoothed by a 3 mm Gaussian.

* ``up_close_slits41.png`` (``--slits``, only this figure; issue 41 item 4): CThead (t = 15) and GE (t = 8)
  at the viewport's 120 x 240, seen from below and outside at the place of the evenly spaced mesh's
  sharpest edge (under an ear): rows and columns evenly spaced, and fitted to the surface's bends
  (``PDEHead.surface(fit_bends=True)``, what the viewport builds), each with its count of edges > 60 deg.

    python3 scripts/bench/up_close_figures.py [--size 384] [--samples 16] [--face | --cut | --uv | --crown | --slits]
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

import _common  # noqa: E402
import bench_smooth  # noqa: E402
import pdehead_addon as E  # noqa: E402

CASES = {"cthead": 10, "ge": 8}
#: Views the add-on does not name, as (direction the camera looks along, world up).
EXTRA_VIEWS = {
    "GRAZING": ((0.0, 1.0, -0.22), (0.0, 0.0, 1.0)),     # from the front, 12 deg down
    "BOTTOM": ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),       # from below, the face up
}


def uv_grid_material(bpy):
    """A material showing Blender's generated colour grid through the mesh's UVs."""
    mat = bpy.data.materials.get("up close UV grid") or bpy.data.materials.new("up close UV grid")
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    img = bpy.data.images.get("uv grid") or bpy.data.images.new("uv grid", 1024, 1024)
    img.generated_type = "COLOR_GRID"
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def sheet(tiles: list[list[Image.Image]], path: Path) -> None:
    h, w = tiles[0][0].size[1], tiles[0][0].size[0]
    out = Image.new("RGB", (w * len(tiles[0]), h * len(tiles)))
    for i, row in enumerate(tiles):
        for j, tile in enumerate(row):
            out.paste(tile, (j * w, i * h))
    # 256 colours, dithered, and 96 when a wider sheet still passes 1 MB (detail_face.png's ten tiles: 1.04 MB
    # at 256, 0.74 MB at 96): figures stay under 1 MB in the repository, with no visible difference on these
    # shaded surfaces
    for colours in (256, 96):
        out.quantize(colours, dither=Image.Dither.FLOYDSTEINBERG).save(path, optimize=True)
        if path.stat().st_size <= 1024 * 1024:
            break
    print(path, flush=True)


def face_figure(bl, args) -> int:
    """CThead's face up close: marching cubes, the default surface before and after issue 21's envelope."""
    from _common import marching_cubes
    from pdehead_addon import defaults as D
    bpy, objects, render = bl["bpy"], bl["objects"], bl["render"]
    bpy.ops.wm.read_homefile(use_empty=True)
    nu, nv = D.NU.default, D.NV.default
    seg = bench_smooth.load("cthead")
    mc = marching_cubes(seg)
    meshes = [("marching cubes", _common.marching_cubes_mesh(seg.mask, seg.ct))]
    from pdehead_addon.pde import pde_surface as PS
    per_slice = PS.APPROXIMATION_PER_SLICE
    # before: t = 10 and the u smoothing of one slice step (the defaults before issue 21's last stop); after:
    # the add-on's defaults (t = 15, half a slice step)
    for label, t, step in (("t=10 before", 10, 1.0), ("after", D.PATCHES.default, per_slice)):
        PS.APPROXIMATION_PER_SLICE = step
        try:
            head = E.solve_pde(E.extract_boundaries(seg, patches=t, selection=bench_smooth.SELECTION))
        finally:
            PS.APPROXIMATION_PER_SLICE = per_slice
        meshes.append((label if label != "after" else f"t={t} after", head.surface(nu, nv, caps=True)))
    scores = {label: bench_smooth.visible_face(seg, m, mc) for label, m in meshes[1:]}
    # the defaults' surface again, shaded with its CT detail map (the same geometry: bump only)
    detail_label = f"t={D.PATCHES.default} + CT detail"
    meshes.append((detail_label, meshes[-1][1]))
    tip = np.asarray(scores[meshes[-2][0]].get("pronasale") or [0, 0, 0], float)
    coll = objects.study_collection("up close face")
    built = []
    for label, mesh in meshes:
        obj = objects.build_mesh_object(mesh, coll, f"face {label}", smooth=label != "marching cubes")
        obj.data.materials.append(objects.ensure_skin_material())
        if label == detail_label:
            meta = bl["detail_map"].build_detail_map(obj, head, seg, D.DETAIL_RESOLUTION.default,
                                                     D.DETAIL_STRENGTH.default)
            print(f"CT detail map {meta['resolution']} px: smooth {meta['smooth_s']:.2f} s, texels "
                  f"{meta['texels_s']:.2f} s, sampling {meta['sample_s']:.2f} s", flush=True)
        built.append((label, obj))
    # the face's box: 60 mm either side, 70 mm below to 60 mm above the nose tip, 60 mm deep
    lo = 0.001 * (tip + np.array([-60.0, 0.0, -70.0]))
    hi = 0.001 * (tip + np.array([60.0, 60.0, 60.0]))
    tmp = args.out / ".tile_up_close.png"
    rows = []
    for view in ("FRONT", "THREE_QUARTER"):
        row = []
        for label, obj in built:
            render.render_objects_png([obj], tmp, view=view, resolution=(args.size, args.size),
                                      samples=args.samples, bounds=(lo, hi))
            with Image.open(tmp) as im:
                im = im.convert("RGB").copy()
            s = scores.get(label.replace(" + CT detail", " after"))
            text = f"CThead {label}" + (f": face {s['score_mean']:.2f} / {s['score_p95']:.2f} mm" if s else "")
            ImageDraw.Draw(im).text((8, 6), text, fill=(235, 235, 235))
            row.append(im)
        rows.append(row)
    tmp.unlink(missing_ok=True)
    sheet(rows, args.out / "up_close_face.png")
    return 0


def cut_figure(bl, args) -> int:
    """CThead's solid cut at the mid-sagittal plane beside the CT on that plane (issue 21 item 3)."""
    import math

    from pdehead_addon.core.ct_volume import apply_window, intensity_window, sample_ct
    bpy, objects, render = bl["bpy"], bl["objects"], bl["render"]
    bpy.ops.wm.read_homefile(use_empty=True)
    seg = bench_smooth.load("cthead")
    ct = seg.ct
    head = E.solve_pde(E.extract_boundaries(seg, patches=10, selection=bench_smooth.SELECTION))
    window = intensity_window(ct)
    coll = objects.study_collection("up close cut")
    vr = (0.0, math.pi)                                # the patient's right half (x < spine): cut at the midline
    new = objects.build_solid(head, coll, ct=ct, v_range=vr, name="cut after", window=window)
    old = objects.build_solid(head, coll, ct=ct, v_range=vr, name="cut before", window=window, texture_size=128,
                              skin="ct", skin_depth_mm=0.0)            # as before issue 21: the CT on the skin
    tmp = args.out / ".tile_up_close.png"
    lo, hi = render.world_bounds([new])
    tiles = []
    for obj, text in ((old, "before: one 128-px tile a face, CT on the skin"),
                      (new, "after: skin outside, cut faces <= 1 voxel a texel")):
        render.render_objects_png([obj], tmp, view="LEFT", resolution=(args.size, args.size), samples=args.samples,
                                  bounds=(lo, hi))
        with Image.open(tmp) as im:
            im = im.convert("RGB").copy()
        ImageDraw.Draw(im).text((8, 6), text, fill=(235, 235, 235))
        tiles.append(im)
    tmp.unlink(missing_ok=True)
    # the CT on the plane x = the spine's mean x, over the same box (y across, z up; seen from the left
    # (camera along -x) the patient's front (-y) is on the screen's left)
    x = float(np.mean(head.spine(np.linspace(0, 1, 50))[:, 0]))
    (y0, z0), (y1, z1) = 1000 * np.asarray(lo)[1:], 1000 * np.asarray(hi)[1:]
    span = max(y1 - y0, z1 - z0) * 1.08
    yc, zc = 0.5 * (y0 + y1), 0.5 * (z0 + z1)
    n = args.size
    ys = yc - span / 2 + span * (np.arange(n) + 0.5) / n
    zs = zc + span / 2 - span * (np.arange(n) + 0.5) / n
    Z, Y = np.meshgrid(zs, ys, indexing="ij")
    pts = np.stack([np.full(Z.size, x), Y.ravel(), Z.ravel()], axis=1)
    grey = apply_window(sample_ct(ct, pts), window).reshape(n, n)
    srgb = np.clip(grey, 0, 1) ** (1 / 2.2)                     # the render is sRGB: the same tone for the eye
    im = Image.fromarray((255 * srgb).astype(np.uint8)).convert("RGB")
    ImageDraw.Draw(im).text((8, 6), f"the CT on the plane x = {x:.0f} mm (linear)", fill=(235, 235, 235))
    tiles.append(im)
    sheet([tiles], args.out / "up_close_cut.png")
    return 0


def slits_figure(bl, args) -> int:
    """The ear from below at 120 x 240: evenly spaced rows and columns beside the bend-fitted mesh."""
    from pdehead_addon import defaults as D
    from pdehead_addon.validation.surface_quality import edge_bends
    bpy, objects, render = bl["bpy"], bl["objects"], bl["render"]
    bpy.ops.wm.read_homefile(use_empty=True)
    tmp = args.out / ".tile_up_close.png"
    rows = []
    for name, t in (("cthead", D.PATCHES.default), ("ge", 8)):
        seg = bench_smooth.load(name)
        head = E.solve_pde(E.extract_boundaries(seg, patches=t, samples=D.SAMPLES.default,
                                                selection=bench_smooth.SELECTION))
        meshes = [(label, head.surface(120, 240, caps=True, fit_bends=fit))
                  for label, fit in (("even", False), ("fitted (viewport)", True))]
        # the place of the even mesh's sharpest edge off the bottom ring, seen from below and outside
        even = meshes[0][1]
        bends = edge_bends(even)
        worst_u, worst_v = _worst_edge_uv(even, bends)
        point = head.evaluate(worst_u, worst_v)
        axis = head.spine(np.array([worst_u]))[0]
        out = np.append((point - axis)[:2], 0.0)
        out /= np.linalg.norm(out)
        ear_view = (tuple(-out + np.array([0.0, 0.0, 0.9])), (0.0, 0.0, 1.0))
        lo, hi = (point - 28.0) * 1e-3, (point + 28.0) * 1e-3
        coll = objects.study_collection(f"slits {name}")
        row = []
        for label, mesh in meshes:
            obj = objects.build_mesh_object(mesh, coll, f"{name} {label}"[:30], smooth=True)
            obj.data.materials.append(objects.ensure_skin_material())
            b = edge_bends(mesh)
            render.render_objects_png([obj], tmp, view=ear_view, resolution=(args.size, args.size),
                                      samples=args.samples, bounds=(lo, hi))
            with Image.open(tmp) as im:
                im = im.convert("RGB").copy()
            ImageDraw.Draw(im).text((8, 6), f"{name} 120x240 {label}: {(b > 60).sum()} edges > 60 deg, "
                                            f"worst {b.max():.0f}", fill=(235, 235, 235))
            row.append(im)
            _common.remove_object(obj)
        rows.append(row)
    tmp.unlink(missing_ok=True)
    sheet(rows, args.out / "up_close_slits41.png")
    return 0


def _worst_edge_uv(mesh, bends) -> tuple[float, float]:
    """(u, v) of the midpoint of the mesh's sharpest edge (:func:`.surface_quality.edge_bends` order)."""
    polys = [np.asarray(f, np.int64) for f in (mesh.quads, mesh.triangles) if len(f)]
    a = np.concatenate([f.ravel() for f in polys])
    b = np.concatenate([np.roll(f, -1, axis=1).ravel() for f in polys])
    n = len(mesh.vertices)
    key = np.sort(np.minimum(a, b) * n + np.maximum(a, b), kind="stable")
    pair = np.nonzero(key[1:] == key[:-1])[0]
    k = key[pair[int(np.argmax(bends))]]
    lo, hi = k // n, k % n
    u, v = (np.asarray(mesh.vertex_attributes[x], float) for x in ("u", "v"))
    return 0.5 * (u[lo] + u[hi]), float(np.angle(np.exp(1j * v[lo]) + np.exp(1j * v[hi])))


def crown_figure(bl, args) -> int:
    """CThead's crown from above and grazing: before / after ``crown_low_pass`` and the 3 mm-smoothed mask."""
    from unittest import mock

    from scipy import ndimage
    from skimage import measure

    from pdehead_addon.pde import pde_spline, pde_surface
    bpy, objects, render = bl["bpy"], bl["objects"], bl["render"]
    bpy.ops.wm.read_homefile(use_empty=True)
    from pdehead_addon import defaults as D
    seg = bench_smooth.load("cthead")
    bset = E.extract_boundaries(seg, patches=D.PATCHES.default, selection=bench_smooth.SELECTION)
    off = lambda c, h, sp, d: pde_spline.crown_low_pass(c, h, sp, d, sigma_mm=0.0)   # noqa: E731
    with mock.patch.object(pde_surface, "crown_low_pass", off):
        before = E.solve_pde(bset).surface(400, 800, caps=True)
    after = E.solve_pde(bset).surface(400, 800, caps=True)
    sm = ndimage.gaussian_filter(seg.mask.astype(np.float32), 3.0 / np.asarray(seg.ct.spacing, float))
    verts, tris, _, _ = measure.marching_cubes(sm, 0.5)
    mc = E.Mesh(vertices=seg.ct.index_to_patient(verts), quads=np.zeros((0, 4), np.int64),
                triangles=np.asarray(tris, np.int64)[:, ::-1])
    coll = objects.study_collection("up close crown")
    built = []
    for label, mesh in (("before: no crown low-pass", before), ("after: crown low-pass", after),
                        ("marching cubes, mask smoothed 3 mm", mc)):
        obj = objects.build_mesh_object(mesh, coll, label[:20], smooth=True)
        obj.data.materials.append(objects.ensure_skin_material())
        built.append((label, obj))
    lo, hi = render.world_bounds([built[1][1]])
    top = np.array(hi, float)
    crown_lo = np.array([0.5 * (lo[0] + hi[0]) - 0.06, 0.5 * (lo[1] + hi[1]) - 0.06, top[2] - 0.035])
    crown_hi = np.array([0.5 * (lo[0] + hi[0]) + 0.06, 0.5 * (lo[1] + hi[1]) + 0.06, top[2]])
    tmp = args.out / ".tile_up_close.png"
    rows = []
    for view in ("TOP", "GRAZING"):
        row = []
        for label, obj in built:
            render.render_objects_png([obj], tmp, view=EXTRA_VIEWS.get(view, view), resolution=(args.size, args.size),
                                      samples=args.samples, bounds=(crown_lo, crown_hi))
            with Image.open(tmp) as im:
                im = im.convert("RGB").copy()
            ImageDraw.Draw(im).text((8, 6), f"CThead {label}, {view.lower()}", fill=(235, 235, 235))
            row.append(im)
        rows.append(row)
    tmp.unlink(missing_ok=True)
    sheet(rows, args.out / "up_close_crown41.png")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    ap.add_argument("--face", action="store_true", help="only up_close_face.png (issue 21 item 1)")
    ap.add_argument("--cut", action="store_true", help="only up_close_cut.png (issue 21 item 3)")
    ap.add_argument("--uv", action="store_true", help="only up_close_uv.png (issue 21 item 4)")
    ap.add_argument("--crown", action="store_true", help="only up_close_crown41.png (issue 41 item 2)")
    ap.add_argument("--slits", action="store_true", help="only up_close_slits41.png (issue 41 item 4)")
    args = ap.parse_args(argv)
    bl = _common.blender()
    if args.face:
        return face_figure(bl, args)
    if args.cut:
        return cut_figure(bl, args)
    if args.crown:
        return crown_figure(bl, args)
    if args.slits:
        return slits_figure(bl, args)
    bpy, objects, render = bl["bpy"], bl["objects"], bl["render"]
    bpy.ops.wm.read_homefile(use_empty=True)
    from pdehead_addon import defaults as D
    nu, nv = D.NU.default, D.NV.default
    tmp = args.out / ".tile_up_close.png"
    crown, neck, uv = [], [], []
    for name, t in CASES.items():
        if args.uv and name != "cthead":
            continue
        seg = bench_smooth.load(name)
        head = E.solve_pde(E.extract_boundaries(seg, patches=t, selection=bench_smooth.SELECTION))
        coll = objects.study_collection(f"up close {name}")
        meshes = [("before", bench_smooth.legacy_surface(head, nu, nv)), ("after", head.surface(nu, nv, caps=True))]
        built = []
        for label, mesh in meshes:
            obj = objects.build_mesh_object(mesh, coll, f"{name} {label}", smooth=True)
            obj.data.materials.append(objects.ensure_skin_material())
            built.append((label, obj))
        bounds = render.world_bounds([o for _, o in built])

        def tile(obj, view, text, bounds=bounds):
            render.render_objects_png([obj], tmp, view=EXTRA_VIEWS.get(view, view), resolution=(args.size, args.size),
                                      samples=args.samples, bounds=bounds)
            with Image.open(tmp) as im:
                im = im.convert("RGB").copy()
            ImageDraw.Draw(im).text((8, 6), text, fill=(235, 235, 235))
            return im
        if not args.uv:
            crown.append([tile(obj, "TOP", f"{name} t={t} {label}: crown from above") for label, obj in built])
            neck.append([tile(obj, "BOTTOM", f"{name} t={t} {label}: neck from below") for label, obj in built])
        if name == "cthead":
            mat = uv_grid_material(bpy)
            for _label, obj in built:
                obj.data.materials[0] = mat
            uv.append([tile(obj, view, f"{name} {label}: UV grid, {view.lower().replace('_', '-')}")
                       for label, obj in built for view in ("FRONT", "THREE_QUARTER")])
        for _, obj in built:
            _common.remove_object(obj)
    tmp.unlink(missing_ok=True)
    if not args.uv:
        sheet(crown, args.out / "up_close_crown.png")
        sheet(neck, args.out / "up_close_neck.png")
    sheet(uv, args.out / "up_close_uv.png")
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())
