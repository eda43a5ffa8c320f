#!/usr/bin/env python3
"""Renders of the face from the skull (issue 23) into docs/figures/face_from_skull_<head>.png (Cycles CPU).

Called by ``scripts/bench/bench_face.py --figures`` with what it measured (one head per figure): the real skin
(marching cubes of the full CT's head mask), the approximation made from the skull alone, and the real
skin coloured by its signed distance to the approximation (blue: the approximation lies outside the real
skin, red: inside; white within +-2.5 mm; grey: outside the scored face region, which leaves out the
scan's cut), each from the front and in profile (the patient's right side), same framing in every picture.

    python3 scripts/bench/bench_face.py --only cthead --figures --no-write
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
SIZE = 300
BAND = 2.5


def deviation_colours(signed: np.ndarray, in_region: np.ndarray) -> np.ndarray:
    """RGBA per vertex: white within +-BAND mm, to full blue (approximation outside) / red (inside) at 8 mm."""
    t = np.clip((np.abs(signed) - BAND) / (8.0 - BAND), 0.0, 1.0)
    out = np.ones((len(signed), 4))
    red, blue = signed > 0, signed < 0
    out[red, 1] = out[red, 2] = 1.0 - t[red]
    out[blue, 0] = out[blue, 1] = 1.0 - t[blue]
    out[~in_region, :3] = 0.55
    return out


def signed_distance(points: np.ndarray, mesh) -> np.ndarray:
    """Distance (mm) from points to the mesh, + where the point lies outside it (real skin outside)."""
    from scipy.spatial import cKDTree

    from pdehead_addon.forensic.tissue_depth import vertex_normals
    from pdehead_addon.validation.surface_metrics import point_surface_distance, triangulate
    faces = np.concatenate([triangulate(mesh.quads), mesh.triangles])
    d = point_surface_distance(points, mesh.vertices, faces, seed=3)
    _, nearest = cKDTree(mesh.vertices).query(points)
    side = np.einsum("ij,ij->i", points - mesh.vertices[nearest], vertex_normals(mesh)[nearest])
    return np.where(side >= 0, d, -d)


def render_face_figures(name: str, keep: dict, out_dir: Path = OUT, views=("FRONT", "RIGHT")) -> Path:
    """One figure per head: real skin, approximation and deviation (columns), one row per view
    (:data:`operators.scene.render.VIEWS`: e.g. ``THREE_QUARTER`` for trials); written to ``out_dir``."""
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fig-"))
    import bpy

    import pdehead
    from pdehead_addon import Mesh
    from pdehead_addon.validation.surface_metrics import face_window, visible_face_points
    addon = pdehead.register_addon()
    render, objects = addon.operators.scene.render, addon.operators.scene.objects
    bpy.ops.wm.read_homefile(use_empty=True)
    coll = objects.study_collection(f"face {name}")

    v, f = keep["skin"]
    centre = keep["a"]["bone_centre"][:2]
    in_region = visible_face_points(v, centre) & face_window(v, centre, keep["tip"])
    if keep.get("inside") is not None:                  # the scored region: not the scan's cut (bench_face.inside_scan)
        in_region[in_region] = keep["inside"](v[in_region], centre)
    signed = np.zeros(len(v))
    signed[in_region] = signed_distance(v[in_region], keep["a"]["result"].mesh)
    skin = Mesh(v, np.zeros((0, 4)), f[:, ::-1].copy(),
                vertex_attributes={"deviation": deviation_colours(signed, in_region)})
    face = keep["a"]["result"].mesh

    def material(mat_name, colour=None, attribute=None):
        mat = bpy.data.materials.new(mat_name)
        if mat.node_tree is None:
            mat.use_nodes = True
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        bsdf.inputs["Roughness"].default_value = 0.55
        if attribute:
            node = mat.node_tree.nodes.new("ShaderNodeAttribute")
            node.attribute_name = attribute
            mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            bsdf.inputs["Base Color"].default_value = colour
        return mat

    real = objects.build_mesh_object(Mesh(v, np.zeros((0, 4)), f[:, ::-1].copy()), coll, "real skin")
    real.data.materials.append(material("real", (0.80, 0.62, 0.52, 1.0)))
    approx = objects.build_mesh_object(face, coll, "approximation")
    approx.data.materials.append(material("approx", (0.72, 0.70, 0.66, 1.0)))
    heat = objects.build_mesh_object(skin, coll, "deviation")
    heat.data.materials.append(material("heat", attribute="deviation"))
    # frame every picture on the real skin's face region and a bit around it (same bounds for all)
    world = v * 0.001
    lo = np.array([world[:, 0].min(), world[:, 1].min(), (keep["tip"][2] - 95) * 0.001])
    hi = np.array([world[:, 0].max(), world[:, 1].max(), (keep["tip"][2] + 75) * 0.001])
    bounds = (lo, hi)                                   # world metres (objects keep world = patient x 0.001)
    for obj in (real, approx, heat):
        obj.hide_render = True
    tmp = Path(tempfile.mkdtemp())
    pics = []
    labels = ("real face (full CT)", "approximation (skull only)", "deviation (blue: approx. outside)")
    for view in views:
        for obj in (real, approx, heat):
            obj.hide_render = False
            path = tmp / f"{obj.name}_{view}.png"
            render.render_objects_png([obj], path, view=view, resolution=(SIZE, SIZE), samples=16, bounds=bounds)
            obj.hide_render = True
            pics.append(Image.open(path).convert("RGB"))
    fig = Image.new("RGB", (3 * SIZE, len(views) * (SIZE + 18)), (255, 255, 255))
    draw = ImageDraw.Draw(fig)
    for i, pic in enumerate(pics):
        row, col = divmod(i, 3)
        fig.paste(pic, (col * SIZE, row * (SIZE + 18) + 18))
        view_name = views[row].lower().replace("right", "profile").replace("_", " ")
        draw.text((col * SIZE + 6, row * (SIZE + 18) + 3), f"{name}: {labels[col]}, {view_name}", fill=(0, 0, 0))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"face_from_skull_{name}.png"
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(target, optimize=True)
    print(f"wrote {target}", file=sys.stderr)
    return target


def error_map_png(points: np.ndarray, tip: np.ndarray, centre_xy, signed: np.ndarray, path: Path, title: str = "",
                  cell: int = 14, lim_mm: float = 6.0) -> Path:
    """The per-region signed error map (issue 23's eighth session): the median signed distance of the real face's
    points to the approximation (:func:`signed_distance`: red, real skin outside = the approximation too thin;
    blue, too thick; white within +-1 mm) per 5 mm of height about the real pronasale (rows, top = up) x 5 degrees
    around the vertical axis from straight ahead (columns, the patient's right on the left as seen from the front),
    as a small PNG; a cell with fewer than 5 points is grey."""
    rel = points[:, :2] - np.asarray(centre_xy, float)[:2]
    angle = np.degrees(np.arctan2(rel[:, 0], -rel[:, 1]))
    dz = points[:, 2] - tip[2]
    zb, ab = np.arange(-70.0, 61.0, 5.0), np.arange(-60.0, 61.0, 5.0)
    iz, ia = np.digitize(dz, zb) - 1, np.digitize(angle, ab) - 1
    K, M = len(zb) - 1, len(ab) - 1
    ok = (iz >= 0) & (iz < K) & (ia >= 0) & (ia < M)
    key = iz[ok] * M + ia[ok]
    order = np.argsort(key, kind="stable")
    keys, starts, counts = np.unique(key[order], return_index=True, return_counts=True)
    med = np.full(K * M, np.nan)
    med[keys] = [np.median(v) for v in np.split(signed[ok][order], starts[1:])]
    med[keys[counts < 5]] = np.nan
    med = med.reshape(K, M)
    t = np.clip(np.nan_to_num(med) / lim_mm, -1.0, 1.0)
    rgb = np.ones((K, M, 3))
    rgb[..., 1] = 1.0 - np.abs(t)
    rgb[..., 2] = np.where(t > 0, 1.0 - t, 1.0)
    rgb[..., 0] = np.where(t < 0, 1.0 + t, 1.0)
    rgb[np.isnan(med)] = 0.6
    img = Image.fromarray((255 * rgb[::-1]).astype(np.uint8)).resize((M * cell, K * cell), Image.NEAREST)
    fig = Image.new("RGB", (M * cell + 60, K * cell + 40), (255, 255, 255))
    fig.paste(img, (50, 20))
    draw = ImageDraw.Draw(fig)
    draw.text((4, 4), title or f"median signed mm, +-{lim_mm:g} full colour (red: approx. inside)", fill=(0, 0, 0))
    for z in range(-60, 61, 20):                                      # height labels (mm about pronasale)
        y = 20 + int((zb[-1] - z) / 5.0 * cell)
        draw.text((4, y - 6), f"{z:+d}", fill=(0, 0, 0))
    for a in (-60, -30, 0, 30, 60):
        draw.text((50 + int((a - ab[0]) / 5.0 * cell) - 8, K * cell + 24), f"{a:+d}", fill=(0, 0, 0))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.save(path)
    return path


def render_suite_figure(label: str, face, out_dir: Path = OUT, views=("FRONT", "RIGHT", "THREE_QUARTER")) -> Path:
    """One robustness-suite run's face (bench_face.py --suite): the approximation alone, front, profile and
    three-quarter, in one strip written to ``out_dir / face_suite_<slug>.png``."""
    import re

    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-fig-"))
    import bpy

    import pdehead
    addon = pdehead.register_addon()
    render, objects = addon.operators.scene.render, addon.operators.scene.objects
    bpy.ops.wm.read_homefile(use_empty=True)
    coll = objects.study_collection("face suite")
    obj = objects.build_mesh_object(face, coll, "approximation")
    mat = bpy.data.materials.new("approx")
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Roughness"].default_value = 0.55
    bsdf.inputs["Base Color"].default_value = (0.72, 0.70, 0.66, 1.0)
    obj.data.materials.append(mat)
    world = face.vertices * 0.001
    top = world[:, 2].max()
    lo = np.array([world[:, 0].min(), world[:, 1].min(), max(world[:, 2].min(), top - 0.26)])
    hi = np.array([world[:, 0].max(), world[:, 1].max(), top])
    tmp = Path(tempfile.mkdtemp())
    pics = []
    for view in views:
        path = tmp / f"{view}.png"
        render.render_objects_png([obj], path, view=view, resolution=(SIZE, SIZE), samples=16, bounds=(lo, hi))
        pics.append(Image.open(path).convert("RGB"))
    fig = Image.new("RGB", (len(views) * SIZE, SIZE + 18), (255, 255, 255))
    draw = ImageDraw.Draw(fig)
    for i, pic in enumerate(pics):
        fig.paste(pic, (i * SIZE, 18))
    draw.text((6, 3), label, fill=(0, 0, 0))
    slug = re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")[:60]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"face_suite_{slug}.png"
    fig.quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(target, optimize=True)
    print(f"wrote {target}", file=sys.stderr)
    return target
