"""Benchmark of the CT detail as geometry and of the print-resolution skin: CThead (and GE) up close.

For CThead at the add-on's defaults (automatic slices, t = 15) and the GE tilted series (t = 8):

* the print resolution (:func:`pdehead_addon.print_resolution`): rows x columns, triangles, the largest
  chord error over the face window and everywhere, watertight;
* CThead's skin as Export for Printing writes it (the print mesh displaced at strength 0, 0.5, 1 by the
  default detail map) against marching cubes of the head mask: the visible-face distance
  (``validation.surface_metrics.visible_face_distance``), beside the viewport's 120 x 240 skin (what
  skin.stl was before) and marching cubes of the mask smoothed by 1.2 mm (the floor of a smooth surface);
* slice banding on the face: per 1 degree column of the face window the outermost radius every 0.5 mm of
  height, minus its Gaussian of 3 mm along z; the RMS of that (mm). Marching cubes of the 1.2 mm-smoothed
  mask is the bar (its slice steps and the face's own features);
* the cost: the map's build (median of ``--repeats``), the print mesh and its displacement.

Results go to ``docs/benchmarks_detail.json`` and the ``detail`` section of ``docs/benchmarks.md``.

    python3 scripts/bench/bench_detail.py [--repeats 3] [--no-ge]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
for _p in (str(ROOT), str(ROOT / "scripts"), str(ROOT / "scripts" / "bench")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import bench_smooth as BS  # noqa: E402
import pdehead_addon as E  # noqa: E402
import write_docs  # noqa: E402
from _common import load_segmentation, marching_cubes  # noqa: E402
from pdehead_addon import defaults as D  # noqa: E402
from pdehead_addon.pde import detail_displace as DDX  # noqa: E402

TARGETS = {"face_mean": 0.20, "face_p95": 0.50, "chord_mm": DDX.PRINT_CHORD_MM,
           "triangles": DDX.PRINT_MAX_TRIANGLES}
STRENGTHS = (0.0, 0.5, 1.0)


def _faces(mesh):
    return np.concatenate([mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]], mesh.triangles]) \
        if len(mesh.quads) else mesh.triangles


def face_banding(vertices, faces, centre_xy, tip, **kw) -> float:
    """RMS (mm) of the face's outermost radius minus its Gaussian of 3 mm along z
    (:func:`pdehead_addon.validation.surface_metrics.face_banding`)."""
    from pdehead_addon.validation.surface_metrics import face_banding as banding
    return banding(vertices, faces, centre_xy, tip, **kw)


def smoothed_mask_mesh(seg, sigma_mm: float = 1.2):
    from scipy import ndimage
    from skimage import measure
    sm = ndimage.gaussian_filter(seg.mask.astype(np.float32), sigma_mm / np.asarray(seg.ct.spacing, float))
    verts, faces, _, _ = measure.marching_cubes(sm, 0.5)
    return seg.ct.index_to_patient(verts), faces


def run(repeats: int, ge: bool) -> dict:
    res: dict = {"load_start": os.getloadavg()[0], "datasets": {}}
    for name, t in (("cthead", D.PATCHES.default), ("ge", 8))[: 2 if ge else 1]:
        seg = load_segmentation(name)
        head = E.solve_pde(E.extract_boundaries(seg, patches=t, selection=D.SELECTION.default))
        t0 = time.perf_counter()
        rows, nv = E.print_resolution(head)
        nu = len(rows)
        pr_s = time.perf_counter() - t0
        window = DDX.surface_window(head)
        row: dict = {"t": t, "print": {"nu": nu, "nv": nv, "seconds": pr_s,
                                       "viewport_chord_face": DDX.chord_error(head, D.NU.default, D.NV.default,
                                                                              window)}}
        with DDX.print_columns(head, window):             # the print's columns (denser over the face)
            row["print"]["chord_face"] = DDX.chord_error(head, nu, nv, window, rows=rows)
            row["print"]["chord_all"] = DDX.chord_error(head, nu, nv, rows=rows)
        flat = E.print_mesh(head)                         # as the export writes it (strength 0)
        row["print"]["triangles"] = int(2 * len(flat.quads) + len(flat.triangles))
        row["print"]["watertight"] = bool(flat.is_watertight())
        if name == "cthead":
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                dmap = E.ct_detail_map(head, seg.mask, seg.ct)
                times.append(time.perf_counter() - t0)
            row["map_s"] = float(np.median(times))
            mc = marching_cubes(seg)
            centre = BS.mask_centre(seg)[:2]
            viewport = head.surface(D.NU.default, D.NV.default, caps=True)
            base = BS.visible_face(seg, viewport, mc)
            tip = np.asarray(base["pronasale"], float)
            row["viewport"] = {"score_mean": base["score_mean"], "score_p95": base["score_p95"],
                               "banding_mm": face_banding(viewport.vertices, _faces(viewport), centre, tip)}
            sv, sf = smoothed_mask_mesh(seg)
            floor = BS.face_floor(seg, mc)
            row["smoothed_mask"] = {**floor, "banding_mm": face_banding(sv, sf, centre, tip)}
            row["marching_cubes_banding_mm"] = face_banding(mc[0], mc[1], centre, tip)
            row["strengths"] = {}
            for s in STRENGTHS:
                t0 = time.perf_counter()
                mesh = DDX.displace_mesh(flat, dmap.height, s, DDX.uv_island_layout(head))
                disp_s = time.perf_counter() - t0
                r = BS.visible_face(seg, mesh, mc)
                row["strengths"][f"{s:g}"] = {"score_mean": r["score_mean"], "score_p95": r["score_p95"],
                                              "banding_mm": face_banding(mesh.vertices, _faces(mesh), centre, tip),
                                              "watertight": bool(mesh.is_watertight()), "displace_s": disp_s}
                print(name, s, row["strengths"][f"{s:g}"], flush=True)
        res["datasets"][name] = row
        print(name, json.dumps(row, default=float)[:1500], flush=True)
    res["load_end"] = os.getloadavg()[0]
    return res


def markdown(res: dict) -> str:
    T = TARGETS
    c = res["datasets"]["cthead"]
    lines = ["## CT detail as geometry, skin at print resolution: `python3 scripts/bench/bench_detail.py`", "",
             f"CThead at the add-on's defaults (automatic slices, t = {c['t']}); the skin as Export for Printing "
             "writes it (the print mesh, displaced at the strength by the default 1024 px detail map), against "
             "marching cubes of the head mask (`visible_face_distance`). Banding: RMS of the face's outermost "
             "radius minus its 3 mm Gaussian along z (1 deg x 0.5 mm bins). Machine load average (2 cores, "
             f"shared): {res['load_start']:.1f} at the start, {res['load_end']:.1f} at the end.", "",
             f"| skin | visible face mean / p95, mm (≤ {T['face_mean']} / ≤ {T['face_p95']} at strength 1) "
             "| banding RMS, mm | watertight |", "|---|---|---|---|"]
    v = c["viewport"]
    lines.append(f"| before: viewport mesh {D.NU.default} x {D.NV.default} | {v['score_mean']:.3f} / "
                 f"{v['score_p95']:.3f} | {v['banding_mm']:.3f} | yes |")
    for s, r in c["strengths"].items():
        lines.append(f"| print mesh {c['print']['nu']} x {c['print']['nv']}, strength {s} | {r['score_mean']:.3f} / "
                     f"{r['score_p95']:.3f} | {r['banding_mm']:.3f} | {'yes' if r['watertight'] else 'NO'} |")
    m = c["smoothed_mask"]
    lines.append(f"| marching cubes of the 1.2 mm-smoothed mask (the bar) | "
                 f"{m['score_mean']:.3f} / {m['score_p95']:.3f} "
                 f"| {m['banding_mm']:.3f} | |")
    lines.append(f"| marching cubes of the mask | 0 / 0 | {c['marching_cubes_banding_mm']:.3f} | |")
    lines += ["", f"| print resolution | rows x columns | triangles (≤ {T['triangles']:,}) | chord error over the "
              f"face, max mm (≤ {T['chord_mm']}) | everywhere, max / p99 mm | at the viewport's {D.NU.default} x "
              f"{D.NV.default}: face max mm | print_resolution s |", "|---|---|---|---|---|---|---|"]
    for name, d in res["datasets"].items():
        p = d["print"]
        lines.append(f"| {name} t={d['t']} | {p['nu']} x {p['nv']} | {p['triangles']:,} | {p['chord_face']['max']:.3f} "
                     f"| {p['chord_all']['max']:.3f} / "
                     f"{p['chord_all']['p99']:.3f} | {p['viewport_chord_face']['max']:.2f} "
                     f"| {p['seconds']:.1f} |")
    lines += ["", f"Detail map build (CThead, 1024 px, median of its runs): {c['map_s']:.1f} s wall; displacing the "
              f"print mesh: {c['strengths']['1']['displace_s']:.2f} s.", "",
              "Notes. *Before*, skin.stl was the viewport's mesh: the file `scripts/pdehead.py --skull --export` wrote "
              "with the code before this change scores the same as the first row (measured on the written file); "
              "the issue's 0.40 / 0.93 for it was not reproduced by this implementation of the measure. Strength 0 "
              "is the PDE surface itself, meshed finer (the first row minus its chord error). The banding figure "
              "counts the face's own features (nose, lips, lids) as well as slice steps, so it is compared with "
              "marching cubes of the 1.2 mm-smoothed mask (the issue's bar), not with 0. The rows are denser over the "
              "face's band of u (`print_rows`, 0.4 as dense elsewhere): with even rows CThead's face kept 0.057 mm "
              "at the 2 M-triangle cap. The columns too are denser over the face's band of v (`print_columns`, 0.4 "
              "as dense elsewhere; at the budget the rows give the columns what their own error does not need): "
              "before, with even columns, CThead took 585 x 1554 rows x columns, 1,906,922 triangles for 0.046 mm "
              "over the face (0.145 / 0.021 mm everywhere) and GE 0.042 mm; the coarser columns away from the face "
              "raise the error there (the table's *everywhere*), which the issue does not bound. The face from the "
              "skull (face.stl) takes the same path (`print_mesh`, `operators/forensic/export.print_face`): on the "
              "phantom "
              "(the test's face) 536 x 1298, 1,487,532 triangles, 0.046 mm over its face window, watertight "
              "(with even columns it stopped at the cap, 617 x 1498, 1.98 M triangles, at 0.069 mm); before, "
              "face.stl was the viewport's 160 x 240 mesh. The eyelid line at strength 1: the map (1024 px texels are "
              "0.56 mm on CThead's face) was not what limited it, the smoothing was: a Gaussian of 1.6 mm along the "
              "slices (`detail_map.SLICE_SIGMA` 0.8 of CThead's 2 mm step, against banding) over a 1 mm crease one "
              "slice high. Now where the PDE surface is upright (|n_z| <= 0.15, blended to 0.35: "
              "`detail_map.UPRIGHT_NZ`) the skin is found in a mask smoothed by only 0.3 of a step along the slices "
              "(`UPRIGHT_SLICE_SIGMA`, 0.6 mm on CThead): there a slice step moves the skin along the normal by "
              "~|n_z| x the step, so the thin Gaussian keeps creases without bringing back bands, and oblique skin "
              "(cheekbones, brows, the crown) keeps the 0.8-step Gaussian. CThead at strength 1 before: 0.178 / "
              "0.498 mm, banding 0.487 mm; tried (thin sigma, |n_z| blend): 0.3, 0.25-0.5: 0.154 / 0.412, 0.523 "
              "(renders: bands under the brows seen from below); 0.3, 0.1-0.3: 0.163 / 0.449, 0.514; 0.4, "
              "0.15-0.35: 0.161 / 0.444, 0.506. Renders: [detail_face_eyes.png](figures/detail_face_eyes.png) "
              "(`detail_figures.py --eyes`), [detail_face_zoom.png](figures/detail_face_zoom.png) (`--zoom`), looked "
              "at: at strength 1 the patient's left lid line is a thin dark line as in marching cubes (before: a "
              "broad soft shadow), the right one faint (marching cubes shows little there either); the two "
              "nostrils separate from below; no regular slice bands, but a faint soft horizontal mottling on the "
              "patient's right cheek beside the nose (front zoom) that was smoother before (the 0.25-0.5 blend "
              "also showed faint lines under the lower lids from below). GE (4 mm slices, t = 8) at strength 1, "
              "measured once: visible face 0.802 -> 0.748 mm mean (p95 7.30 both, not investigated), "
              "banding 1.165 both (its smoothed mask 2.388). The map's cost on CThead: sampling 1.7 -> 2.3 s, the "
              "second Gaussian 0.2 s (median of 3, loaded machine; the table's build time is wall at load ~5).", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-ge", action="store_true")
    ap.add_argument("--json", type=Path, default=ROOT / "docs" / "benchmarks_detail.json")
    ap.add_argument("--md", type=Path, default=ROOT / "docs" / "benchmarks.md")
    ap.add_argument("--markdown-only", action="store_true", help="rewrite the section from --json, no run")
    write_docs.add_arguments(ap, "detail")
    args = ap.parse_args(argv)
    if args.markdown_only or args.from_json:
        write_docs.write("detail", write_docs.load(args.from_json or args.json), args.md)
        return 0
    res = write_docs.save(args.json, run(args.repeats, not args.no_ge), args.repeats)
    write_docs.write("detail", res, args.md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
