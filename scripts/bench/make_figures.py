#!/usr/bin/env python3
"""The paper's figures for CThead, rendered in Blender (Cycles CPU) into docs/figures/.

Regenerate all (a few minutes on 2 cores)::

    python3 scripts/bench/make_figures.py
    python3 scripts/bench/make_figures.py --only fig12,fig14     # some of them
    python3 scripts/bench/make_figures.py --list                 # what there is

3-D figures go through the add-on's own Blender layer, loaded from this repository by
the dev shim (``scripts/_common.py``, ``load_addon``): ``operators/scene/objects.py`` (boundary curves, surface
and solid meshes), ``operators/volume/volume.py`` (the w-field .vdb; its eq. 24 material: ``volume_material.py``) and
``operators/scene/render.py`` (``render_objects_png``: Cycles on the CPU; EEVEE and Workbench
render blank without a GPU). 2-D figures (slices, the Jaccard plot, colour bars) are drawn
with numpy + PIL. Views follow Blender's: FRONT looks along +Y at the face with the
patient's left on the screen's right.

==========  =====================================================================
fig03       the pipeline on four slices: slice, soft segmentation p, cleaned mask, boundary (red)
fig04       boundary curves (t=10), the 40x60 surface flat (with its grid) and shaded
fig10       per-slice Jaccard of the segmentation against the independent reference
fig12       the t-series t = 4, 5, 6, 10, 14, 31
fig13       the uv-series of the paper's Fig. 13
fig14       solid cutaways: full; v in [pi/2, 2pi]; v in [pi/2, 2pi] with w in [0.8, 1]
fig15       volume renders: intuitive (alpha = intensity) against eq. 24 (alpha from w)
deviation   PDE (t=10) against marching cubes: per-vertex distance painted on the surface
==========  =====================================================================
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT))

import _common  # noqa: E402  (data paths, the dev-shim Blender loader, marching cubes)
import bench_segmentation  # noqa: E402  (the reference mask)
import pdehead_addon as E  # noqa: E402

OUT = ROOT / "docs" / "figures"
MAX_BYTES = 150 * 1024
BG = (255, 255, 255)
#: Views the add-on does not name, as (direction the camera looks along, world up): cutaways seen from the
#: back right above (v = 0 .. pi/2 is the posterior-right quadrant), and the front right.
EXTRA_VIEWS = {"BACK_RIGHT_ABOVE": ((0.9, -1.0, -0.3), (0.0, 0.0, 1.0)),
               "FRONT_RIGHT": ((0.55, 1.0, -0.15), (0.0, 0.0, 1.0))}
FIG12_T = (4, 5, 6, 10, 14, 31)
FIG13_UV = ((10, 40), (20, 40), (40, 40), (60, 40), (80, 40), (60, 10), (60, 20), (60, 40), (60, 60), (60, 80))
#: original CThead slice numbers (1 = superior) shown in Fig. 3
FIG3_SLICES = (25, 45, 60, 80)
DEVIATION_MAX_MM = 3.0
#: colour ramp of the deviation map: (position in [0, 1], linear RGB)
DEVIATION_RAMP = ((0.0, (0.02, 0.10, 0.60)), (0.33, (0.05, 0.60, 0.35)), (0.66, (0.95, 0.75, 0.05)),
                  (1.0, (0.80, 0.04, 0.02)))


# ============================================================================= PIL helpers
def font(size: int = 13):
    return ImageFont.load_default(size=size)


def label(im: Image.Image, text: str, size: int = 12, where="tl", colour=(0, 0, 0), box=(255, 255, 255)) -> Image.Image:
    d = ImageDraw.Draw(im)
    f = font(size)
    x0, y0, x1, y1 = d.textbbox((0, 0), text, font=f)
    w, h = x1 - x0, y1 - y0
    x = 3 if "l" in where else im.width - w - 5
    y = 2 if "t" in where else im.height - h - 6
    if box is not None:
        d.rectangle((x - 2, y - 1, x + w + 3, y + h + 4), fill=box)
    d.text((x - x0, y - y0 + 1), text, fill=colour, font=f)
    return im


def grid(tiles: list[Image.Image], cols: int, pad: int = 2, bg=BG) -> Image.Image:
    rows = math.ceil(len(tiles) / cols)
    tw = max(t.width for t in tiles)
    th = max(t.height for t in tiles)
    out = Image.new("RGB", (cols * tw + (cols + 1) * pad, rows * th + (rows + 1) * pad), bg)
    for i, t in enumerate(tiles):
        r, c = divmod(i, cols)
        out.paste(t.convert("RGB"),
                  (pad + c * (tw + pad) + (tw - t.width) // 2, pad + r * (th + pad) + (th - t.height) // 2))
    return out


def title_bar(im: Image.Image, text: str, size: int = 13) -> Image.Image:
    f = font(size)
    d0 = ImageDraw.Draw(im)
    lines = text.split("\n")
    h = (size + 5) * len(lines) + 6
    out = Image.new("RGB", (im.width, im.height + h), BG)
    out.paste(im, (0, h))
    d = ImageDraw.Draw(out)
    for i, line in enumerate(lines):
        d.text((4, 3 + i * (size + 5)), line, fill=(0, 0, 0), font=f)
    del d0
    return out


def save_png(im: Image.Image, path: Path) -> Path:
    """Save as PNG, palette-quantised when the RGB file would exceed MAX_BYTES."""
    path.parent.mkdir(parents=True, exist_ok=True)
    im = im.convert("RGB")
    im.save(path, optimize=True)
    if path.stat().st_size > MAX_BYTES:
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, optimize=True)
    if path.stat().st_size > MAX_BYTES:
        im.quantize(colors=96, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, optimize=True)
    print(f"  wrote {path.relative_to(ROOT)} {im.width}x{im.height} {path.stat().st_size / 1024:.0f} kB", flush=True)
    return path


def grey(img: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (np.clip((img - lo) / (hi - lo), 0, 1) * 255).astype(np.uint8)


def linear_to_srgb(c):
    c = np.clip(np.asarray(c, float), 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def ramp_colour(x: np.ndarray, ramp=DEVIATION_RAMP) -> np.ndarray:
    """Linear-RGB colour of the ramp at x in [0, 1] (linear interpolation like Blender's ColorRamp)."""
    pos = np.array([p for p, _ in ramp])
    col = np.array([c for _, c in ramp])
    x = np.clip(np.asarray(x, float), 0, 1)
    return np.stack([np.interp(x, pos, col[:, i]) for i in range(3)], axis=-1)


# ============================================================================= data (computed once)
class Data:
    """CThead and its pipeline results, computed lazily and cached."""

    def __init__(self):
        self._c = {}

    def _get(self, key, fn):
        if key not in self._c:
            t0 = time.perf_counter()
            self._c[key] = fn()
            print(f"  ({key}: {time.perf_counter() - t0:.1f} s)", flush=True)
        return self._c[key]

    @property
    def ct(self):
        raw16 = _common.SHARED_DATA / "cthead_stanford" / "raw16"
        return self._get("ct", lambda: E.load_ct(raw16, **_common.CTHEAD_RAW16_OPTIONS))

    @property
    def seg(self):
        return self._get("seg", lambda: E.segment_head(self.ct))

    def bset(self, t: int = 10):
        return self._get(f"bset{t}", lambda: _common.boundaries(self.seg, t, 256))

    def head(self, t: int = 10):
        return self._get(f"head{t}", lambda: E.solve_pde(self.bset(t)))

    @property
    def reference(self):
        return self._get("reference", lambda: bench_segmentation.reference_for("cthead", self.ct)[0])

    @property
    def mc(self):
        return self._get("mc", lambda: _common.marching_cubes_mesh(self.seg.mask, self.ct))


# ============================================================================= Blender helpers
class Blender:
    def __init__(self, samples: int):
        self.bl = _common.blender()
        self.bpy = self.bl["bpy"]
        self.objects, self.volume, self.render = self.bl["objects"], self.bl["volume"], self.bl["render"]
        self.volume_material = self.bl["volume_material"]
        self.samples = samples
        self.tmp = Path(tempfile.mkdtemp(prefix="pdehead-figs-"))
        self.n = 0

    def reset(self):
        self.bpy.ops.wm.read_homefile(use_empty=True)  # empty scene; preferences and add-ons untouched

    def collection(self, name="figure"):
        return self.objects.study_collection(name)

    def png(self, objs, view="FRONT", size=(200, 240), bounds=None, samples=None, **kw) -> Image.Image:
        self.n += 1
        path = self.tmp / f"r{self.n}.png"
        self.render.render_objects_png(objs, path, view=EXTRA_VIEWS.get(view, view), resolution=size,
                                       samples=samples or self.samples, bounds=bounds, **kw)
        with Image.open(path) as im:
            return im.convert("RGB").copy()

    def material(self, name, base=(0.8, 0.55, 0.44), roughness=0.55):
        mat = self.bpy.data.materials.get(name) or self.bpy.data.materials.new(name)
        mat.use_nodes = True
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        bsdf.inputs["Base Color"].default_value = (*base, 1.0)
        bsdf.inputs["Roughness"].default_value = roughness
        return mat

    def add_wire(self, obj, thickness_mm=0.35, colour=(0.05, 0.05, 0.05)):
        """Show the mesh's quad grid: a Wireframe modifier (keeps the faces) with a dark second material."""
        mat = self.material("figure wire", base=colour, roughness=0.9)
        if len(obj.data.materials) == 0:
            obj.data.materials.append(self.objects.ensure_skin_material())
        obj.data.materials.append(mat)
        mod = obj.modifiers.new("grid", "WIREFRAME")
        mod.thickness = thickness_mm * 0.001
        mod.use_replace = False
        mod.use_even_offset = False
        mod.offset = 0.0
        mod.material_offset = len(obj.data.materials) - 1
        return obj

    def mesh(self, mesh, coll, name, smooth=True, material=None):
        obj = self.objects.build_mesh_object(mesh, coll, name, smooth=smooth)
        obj.data.materials.append(material or self.objects.ensure_skin_material())
        return obj

    def bounds_of(self, objs):
        return self.render.world_bounds(objs)


def union_bounds(bs):
    lo = np.min([b[0] for b in bs], axis=0)
    hi = np.max([b[1] for b in bs], axis=0)
    return lo, hi


# ============================================================================= figures
def fig03(data: Data, bl: Blender | None, args) -> list[Path]:
    """Pipeline on four slices: CT, soft segmentation p (eq. 16-21), cleaned mask, boundary (eq. 22) in red."""
    from pdehead_addon.curves.slice_outlines import boundary_ring
    ct, seg = data.ct, data.seg
    nz = ct.shape[0]
    ks = [nz - n for n in FIG3_SLICES]  # loaded k points superior; file 1 is the top slice
    lo, hi = 0.0, 1400.0
    tile = 108
    rows = {"CT slice": [], "soft\nsegmentation p\n(eq. 16-21)": [], "cleaned mask\n(largest comp.,\nholes filled)": [],
            "boundary\n(eq. 22, red)": []}
    for n, k in zip(FIG3_SLICES, ks):
        sl = grey(ct.data[k], lo, hi)
        p = (np.clip(seg.probability[k], 0, 1) * 255).astype(np.uint8)
        m = seg.mask[k].astype(np.uint8) * 255
        rgb = np.stack([sl] * 3, axis=-1)
        ring = boundary_ring(seg.mask[k])
        ring = ring | np.roll(ring, 1, 0) | np.roll(ring, 1, 1)  # 2 px so that it survives the down-scaling
        rgb[ring] = (235, 20, 20)
        for name, a in zip(rows, (sl, p, m, rgb)):
            im = Image.fromarray(a).resize((tile, tile), Image.LANCZOS if a.ndim == 2 else Image.BILINEAR)
            rows[name].append(label(im.convert("RGB"), f"slice {n}", size=10) if name == "CT slice" else im)
    tiles = [t for name in rows for t in rows[name]]
    g = grid(tiles, 4)
    # row captions on the left
    cap_w = 92
    out = Image.new("RGB", (g.width + cap_w, g.height), BG)
    out.paste(g, (cap_w, 0))
    d = ImageDraw.Draw(out)
    for r, name in enumerate(rows):
        y = 2 + r * (tile + 2) + tile // 2 - 14
        for i, word in enumerate(name.split("\n")):
            d.text((4, y + i * 14), word, fill=(0, 0, 0), font=font(11))
    out = title_bar(out, "Fig. 3  CThead: segmentation and boundary extraction on four slices\n"
                         "(row 0 anterior at the top; the soft p is segment_head's membership before clean-up)", 11)
    return [save_png(out, OUT / "fig03_pipeline.png")]


def fig10(data: Data, bl, args) -> list[Path]:
    """Per-slice Jaccard of the segmentation against the independent reference (paper Fig. 10)."""
    from pdehead_addon.validation.metrics import head_slices, slice_jaccard_on_head
    seg, ref = data.seg, data.reference
    ks = head_slices(ref)
    j = slice_jaccard_on_head(seg.mask, ref)
    nz = seg.mask.shape[0]
    files = nz - ks  # original slice number (1 = superior)
    order = np.argsort(files)
    files, j = files[order], j[order]
    W, H = 480, 260
    ml, mr, mt, mb = 48, 12, 34, 36
    im = Image.new("RGB", (W, H), BG)
    d = ImageDraw.Draw(im)
    ylo = math.floor((float(j.min()) - 0.005) * 100) / 100
    step = 0.01 if 1 - ylo <= 0.06 else 0.05
    x0, x1 = 1, nz
    X = lambda f: ml + (f - x0) / (x1 - x0) * (W - ml - mr)  # noqa: E731
    Y = lambda v: mt + (1 - (v - ylo) / (1 - ylo)) * (H - mt - mb)  # noqa: E731
    f9 = font(10)
    for v in np.arange(ylo, 1.0001, step):
        d.line((ml, Y(v), W - mr, Y(v)), fill=(225, 225, 225))
        d.text((4, Y(v) - 6), f"{v:.2f}", fill=(0, 0, 0), font=f9)
    for f in range(10, nz + 1, 10):
        d.line((X(f), H - mb, X(f), H - mb + 3), fill=(0, 0, 0))
        d.text((X(f) - 7, H - mb + 5), str(f), fill=(0, 0, 0), font=f9)
    d.rectangle((ml, mt, W - mr, H - mb), outline=(0, 0, 0))
    mean = float(j.mean())
    paper = _common.PAPER["jaccard_mean"]
    if paper >= ylo:
        d.line((ml, Y(paper), W - mr, Y(paper)), fill=(150, 150, 150), width=1)
    d.line((ml, Y(mean), W - mr, Y(mean)), fill=(40, 110, 220), width=1)
    pts = [(X(f), Y(v)) for f, v in zip(files, j)]
    d.line(pts, fill=(200, 30, 30), width=2)
    for p in pts:
        d.ellipse((p[0] - 1.5, p[1] - 1.5, p[0] + 1.5, p[1] + 1.5), fill=(200, 30, 30))
    # legend, lower left inside the plot
    lx, ly = ml + 8, H - mb - 48
    d.rectangle((lx - 4, ly - 3, lx + 230, ly + 43), fill=(255, 255, 255), outline=(200, 200, 200))
    for i, (colour, text) in enumerate((((200, 30, 30), "segment_head, per slice"),
                                        ((40, 110, 220), f"its mean {mean:.4f}"),
                                        ((150, 150, 150), f"paper's mean (its own ground truth) {paper}"))):
        d.line((lx, ly + 6 + 14 * i, lx + 18, ly + 6 + 14 * i), fill=colour, width=2)
        d.text((lx + 24, ly + 14 * i), text, fill=(0, 0, 0), font=f9)
    d.text((ml, H - 16), "CThead slice (1 = top of the head, 113 = neck)", fill=(0, 0, 0), font=f9)
    d.text((4, 4), "Fig. 10  Jaccard per slice: segment_head vs the independent threshold reference",
           fill=(0, 0, 0), font=font(11))
    d.text((4, 18), f"({_reference_name(data)}, {len(j)} head slices; min {j.min():.3f})", fill=(0, 0, 0),
           font=f9)
    return [save_png(im, OUT / "fig10_jaccard.png")]


def _reference_name(data: Data) -> str:
    return "threshold reference, metrics.REFERENCE_SETTINGS['cthead']"


def fig04(data: Data, bl: Blender, args) -> list[Path]:
    """(a) boundary curves, (b) the 40x60 uv sampling, (c) flat surface with its grid, (d) shaded surface."""
    bl.reset()
    coll = bl.collection("fig04")
    head, bset = data.head(10), data.bset(10)
    curves = bl.objects.build_boundary_curves(bset, coll, bevel_mm=0.9)
    mesh = head.surface(40, 60, caps=True)
    flat = bl.mesh(mesh, coll, "flat", smooth=False)
    bl.add_wire(flat, 0.45)
    shaded = bl.objects.build_surface(head, coll, 40, 60, caps=True, name="shaded")
    bounds = union_bounds([bl.bounds_of([curves]), bl.bounds_of([shaded])])
    size = (150, 180)
    a = label(bl.png([curves], "FRONT_RIGHT", size, bounds), "(a) 31 curves", 11)
    c = label(bl.png([flat], "FRONT_RIGHT", size, bounds), "(c) flat 40x60", 11)
    dd = label(bl.png([shaded], "FRONT_RIGHT", size, bounds), "(d) shaded", 11)
    # (b) the uv parametric grid, drawn
    b = Image.new("RGB", size, BG)
    d = ImageDraw.Draw(b)
    L, R, T, B = 22, size[0] - 8, 22, size[1] - 22
    for i in range(40):
        y = B - i / 39 * (B - T)
        d.line((L, y, R, y), fill=(90, 90, 90))
    for jv in range(61):
        x = L + jv / 60 * (R - L)
        d.line((x, T, x, B), fill=(90, 90, 90))
    d.text((L, B + 4), "v: 0 .. 2pi (60)", fill=(0, 0, 0), font=font(10))
    d.text((2, T - 14), "u: 0..1 (40)", fill=(0, 0, 0), font=font(10))
    label(b, "(b) uv grid", 11, where="tr")
    out = title_bar(grid([a, b, c, dd], 4), "Fig. 4  CThead, t = 10 (31 boundary curves, "
                                            "shape-change selection), 40 x 60 samples", 11)
    return [save_png(out, OUT / "fig04_surface.png")]


def fig12(data: Data, bl: Blender, args) -> list[Path]:
    """The t-series: heads from 3t+1 slices for t = 4, 5, 6, 10, 14, 31."""
    bl.reset()
    objs = {}
    for t in FIG12_T:
        coll = bl.collection(f"fig12 t{t}")
        try:
            head = data.head(t)
        except E.PDEHeadError as exc:
            print(f"  t={t}: {exc}")
            continue
        objs[t] = bl.objects.build_surface(head, coll, nu=max(120, 6 * t + 1), nv=240, caps=True, name=f"t{t}")
        objs[t].hide_render = True
    mc = bl.mesh(data.mc, bl.collection("fig12 mc"), "marching cubes")
    mc.hide_render = True
    bounds = union_bounds([bl.bounds_of([o]) for o in objs.values()])
    tiles = []
    for t, o in list(objs.items()) + [("mc", mc)]:
        o.hide_render = False
        text = f"t={t} ({3 * t + 1} sl.)" if t != "mc" else f"MC ({data.ct.shape[0]} sl.)"
        tiles.append(label(bl.png([o], "FRONT", (118, 142), bounds), text, 10))
        o.hide_render = True
    out = title_bar(grid(tiles, 4), "Fig. 12  CThead PDE heads from 3t+1 slices (the add-on's shape-change\n"
                                    "selection; front view) and marching cubes of the whole mask (Fig. 11c)", 11)
    return [save_png(out, OUT / "fig12_t_series.png")]


def fig13(data: Data, bl: Blender, args) -> list[Path]:
    """The uv-series of the paper's Fig. 13 with the quad grid shown."""
    bl.reset()
    head = data.head(10)
    objs = []
    for i, (nu, nv) in enumerate(FIG13_UV):
        coll = bl.collection(f"fig13 {i}")
        o = bl.mesh(head.surface(nu, nv, caps=True), coll, f"uv{i}", smooth=False)
        bl.add_wire(o, 0.5)
        o.hide_render = True
        objs.append(o)
    bounds = union_bounds([bl.bounds_of([o]) for o in objs])
    tiles = []
    for (nu, nv), o in zip(FIG13_UV, objs):
        o.hide_render = False
        tiles.append(label(bl.png([o], "FRONT_RIGHT", (112, 136), bounds), f"{nu}x{nv}", 10))
        o.hide_render = True
    out = title_bar(grid(tiles, 5), "Fig. 13  CThead, t = 10: uv resolution u x v (top: u varies at v = 40;\n"
                                    "bottom: v varies at u = 60)", 11)
    return [save_png(out, OUT / "fig13_uv_series.png")]


def fig14(data: Data, bl: Blender, args) -> list[Path]:
    """Solid cutaways (eq. 23) coloured by the CT: grid view (top) and smooth view (bottom)."""
    bl.reset()
    head, ct = data.head(10), data.ct
    cases = [("full", (0.0, 2 * math.pi), (0.0, 1.0)),
             ("v in [pi/2, 2pi]", (math.pi / 2, 2 * math.pi), (0.0, 1.0)),
             ("+ w in [0.8, 1]", (math.pi / 2, 2 * math.pi), (0.8, 1.0))]
    objs = []
    for i, (_name, vr, wr) in enumerate(cases):
        coll = bl.collection(f"fig14 {i}")
        o = bl.objects.build_solid(head, coll, 40, 60, 5, v_range=vr, w_range=wr, ct=ct, name=f"solid{i}")
        o.hide_render = True
        objs.append(o)
    # the add-on's CT material shows the colour attribute as base colour; for the figure it also
    # glows a little so that the dark soft tissue stays readable in the shadowed cut faces
    mat = objs[0].data.materials[0]
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    colour = next(n for n in nodes if n.bl_idname == "ShaderNodeVertexColor")
    bsdf = nodes.get("Principled BSDF")
    links.new(colour.outputs["Color"], bsdf.inputs["Emission Color"])
    bsdf.inputs["Emission Strength"].default_value = 0.45
    bounds = union_bounds([bl.bounds_of([o]) for o in objs])
    top, bottom = [], []
    for (name, _, _), o in zip(cases, objs):
        o.hide_render = False
        bottom.append(label(bl.png([o], "BACK_RIGHT_ABOVE", (156, 180), bounds), name, 10))
        bl.add_wire(o, 0.35, colour=(0.9, 0.75, 0.2))
        top.append(label(bl.png([o], "BACK_RIGHT_ABOVE", (156, 180), bounds), name, 10))
        o.hide_render = True
    out = title_bar(grid(top + bottom, 3), "Fig. 14  CThead PDE solid, 40 x 60 x 5 samples, CT intensity as colour\n"
                                           "(seen from behind, right, above; top: grid view, bottom: smooth view)", 11)
    return [save_png(out, OUT / "fig14_solid_cutaways.png")]


def fig15(data: Data, bl: Blender, args) -> list[Path]:
    """Volume renders: intuitive texture mapping (alpha = CT intensity) against eq. 24 (alpha from w)."""
    bl.reset()
    head, ct = data.head(10), data.ct
    wf = head.w_field(ct, ct=ct)
    coll = bl.collection("fig15")
    vdb = bl.tmp / "fig15.vdb"
    vol = bl.volume.build_volume(wf, coll, vdb, name="volume", ct=ct)
    tiles = []
    for mode, view, name in (("INTENSITY", "FRONT", "(a) intuitive: alpha = intensity"),
                             ("EQ24", "FRONT", "(b) eq. 24, front"),
                             ("EQ24", "RIGHT", "(c) eq. 24, side")):
        bl.volume_material.set_volume_settings(vol, alpha_mode=mode, low_alpha=0.1, high_alpha=0.9)
        tiles.append(label(bl.png([vol], view, (160, 190), samples=args.volume_samples), name, 10,
                           colour=(255, 255, 255), box=None))
    out = title_bar(grid(tiles, 3, bg=(0, 0, 0)), "Fig. 15  CThead volume (Cycles): the paper's intuitive texture\n"
                                                  "mapping against eq. 24 on the PDE solid (l=0.1, h=0.9)", 11)
    return [save_png(out, OUT / "fig15_volume.png")]


def deviation(data: Data, bl: Blender, args) -> list[Path]:
    """Per-vertex distance of the PDE surface (t=10) to the marching-cubes mesh, as colour on the surface."""
    from pdehead_addon.validation.surface_metrics import point_surface_distance
    bl.reset()
    head, mc = data.head(10), data.mc
    # as in the fidelity numbers (bench.py's FIDELITY_DEFINITION): the open tube against the MC triangles
    # within the z range of the boundary curves
    z = head.bset.curves[..., 2]
    cz = mc.vertices[mc.triangles][:, :, 2].mean(axis=1)
    faces = mc.triangles[(cz >= z.min()) & (cz <= z.max())]
    mesh = head.surface(161, 256, caps=False)
    dist = point_surface_distance(mesh.vertices, mc.vertices, faces, dense=600_000)
    mesh.vertex_attributes["deviation_mm"] = dist.astype(np.float32)
    coll = bl.collection("deviation")
    mat = deviation_material(bl)
    obj = bl.mesh(mesh, coll, "deviation", smooth=True, material=mat)
    tiles = [label(bl.png([obj], view, (170, 200)), name, 10)
             for view, name in (("FRONT", "front"), ("RIGHT", "right side"), ("BACK", "back"))]
    g = grid(tiles, 3)
    bar = colour_bar(g.width, dist)
    out = Image.new("RGB", (g.width, g.height + bar.height), BG)
    out.paste(g, (0, 0))
    out.paste(bar, (0, g.height))
    out = title_bar(out, "PDE head (t = 10, open tube) against marching cubes of the same mask:\n"
                         "distance of each PDE vertex to the MC surface (same z range)", 11)
    return [save_png(out, OUT / "deviation_pde_vs_mc.png")]


def deviation_material(bl: Blender):
    """Attribute deviation_mm -> Map Range (0..DEVIATION_MAX_MM) -> Color Ramp -> base colour + emission."""
    mat = bl.material("figure deviation", roughness=0.6)
    nt = mat.node_tree
    nodes, links = nt.nodes, nt.links
    bsdf = nodes.get("Principled BSDF")
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "deviation_mm"
    attr.attribute_type = "GEOMETRY"
    mr = nodes.new("ShaderNodeMapRange")
    mr.inputs["From Min"].default_value = 0.0
    mr.inputs["From Max"].default_value = DEVIATION_MAX_MM
    mr.clamp = True
    ramp = nodes.new("ShaderNodeValToRGB")
    els = ramp.color_ramp.elements
    while len(els) > 2:
        els.remove(els[-1])
    for i, (pos, col) in enumerate(DEVIATION_RAMP):
        e = els[i] if i < 2 else els.new(pos)
        e.position = pos
        e.color = (*col, 1.0)
    links.new(attr.outputs["Fac"], mr.inputs["Value"])
    links.new(mr.outputs["Result"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Emission Color"])
    bsdf.inputs["Emission Strength"].default_value = 0.35
    return mat


def colour_bar(width: int, dist: np.ndarray) -> Image.Image:
    h = 46
    im = Image.new("RGB", (width, h), BG)
    d = ImageDraw.Draw(im)
    L, R = 20, width - 20
    x = np.linspace(0, 1, R - L)
    rgb = (linear_to_srgb(ramp_colour(x)) * 255).astype(np.uint8)
    bar = np.repeat(rgb[None], 12, axis=0)
    im.paste(Image.fromarray(bar), (L, 6))
    d.rectangle((L - 1, 5, R, 18), outline=(0, 0, 0))
    f = font(10)
    for v in np.arange(0, DEVIATION_MAX_MM + 1e-9, 0.5):
        xx = L + v / DEVIATION_MAX_MM * (R - L - 1)
        d.line((xx, 18, xx, 21), fill=(0, 0, 0))
        d.text((xx - 8, 22), f"{v:g}" + (" mm+" if v == DEVIATION_MAX_MM else ""), fill=(0, 0, 0), font=f)
    d.text((L, 34), f"mean {dist.mean():.2f} mm, p95 {np.percentile(dist, 95):.2f} mm, max {dist.max():.1f} mm"
                    " (PDE vertices to MC)", fill=(0, 0, 0), font=f)
    return im


FIGURES = {"fig03": (fig03, False), "fig04": (fig04, True), "fig10": (fig10, False), "fig12": (fig12, True),
           "fig13": (fig13, True), "fig14": (fig14, True), "fig15": (fig15, True), "deviation": (deviation, True)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Render the paper's figures for CThead into docs/figures/.")
    p.add_argument("--only", help="comma list of " + ",".join(FIGURES))
    p.add_argument("--list", action="store_true")
    p.add_argument("--samples", type=int, default=24, help="Cycles samples for meshes (default 24)")
    p.add_argument("--volume-samples", type=int, default=24, help="Cycles samples for volumes (default 24)")
    args = p.parse_args(argv)
    if args.list:
        for k, (fn, _) in FIGURES.items():
            print(f"{k:10s} {fn.__doc__.splitlines()[0]}")
        return 0
    names = args.only.split(",") if args.only else list(FIGURES)
    unknown = [n for n in names if n not in FIGURES]
    if unknown:
        p.error(f"unknown figure(s) {unknown}; choose from {list(FIGURES)}")
    data = Data()
    bl = None
    failed = []
    t0 = time.perf_counter()
    for name in names:
        fn, needs_blender = FIGURES[name]
        print(f"== {name}", flush=True)
        t1 = time.perf_counter()
        try:
            if needs_blender and bl is None:
                bl = Blender(args.samples)
            fn(data, bl, args)
        except Exception as exc:  # keep going: report every failing figure at the end
            import traceback
            traceback.print_exc()
            failed.append(f"{name}: {_common.error_text(exc)}")
        print(f"   {time.perf_counter() - t1:.1f} s", flush=True)
    print(f"done in {time.perf_counter() - t0:.0f} s")
    if failed:
        print("FAILED:\n  " + "\n  ".join(failed))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
