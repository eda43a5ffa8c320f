#!/usr/bin/env python3
"""Benchmarks of the PDE step (solver, meshes, w-field, storage, fidelity) on CThead.

Every time is the MEDIAN of ``--repeats`` runs (min and all runs are kept in the JSON);
the peer (``skimage.measure.marching_cubes`` on the same mask) runs in the same process
and run. The measurements are importable functions (``bench_solve_vs_mc``,
``bench_surface``, ``bench_w_field``, ``bench_storage``, ``bench_fidelity``) so that
``scripts/bench/bench.py`` can fold them in.

Usage::

    python3 scripts/bench/bench_pde.py                       # CThead raw16, t = 10, 7 repeats
    python3 scripts/bench/bench_pde.py --repeats 3 --json /tmp/pde.json
    PDEHEAD_DATA=/path/to/data python3 scripts/bench/bench_pde.py
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import pdehead_addon as E  # noqa: E402
from pdehead_addon.pde.pde_surface import align_parameterisation  # noqa: E402
from pdehead_addon.pde.surface_mesh import signed_volume  # noqa: E402

sys.path.insert(0, str(ROOT / "scripts"))
from _common import CTHEAD_RAW16_OPTIONS as CTHEAD_RAW16, PAPER, SHARED_DATA as DATA, timed as _timed, tube_fidelity  # noqa: E402  # noqa: E402

TARGETS = {"speedup": 100.0, "surface_200x400_s": 0.016, "w_field_s": 1.0, "storage_bytes": 16_000,
           "fidelity_t10_mean": 1.0, "fidelity_t10_p95": 3.0, "fidelity_t31_mean": 0.6}


def timed(fn: Callable[[], Any], repeats: int, warmup: bool = True) -> tuple[dict, Any]:
    """:func:`_common.timed` with one untimed warm-up call first (these stages are milliseconds)."""
    return _timed(fn, repeats, warmup=warmup)


def marching_cubes(mask: np.ndarray, ct) -> tuple[np.ndarray, np.ndarray]:
    """The peer: marching cubes (level 0.5) of the mask, vertices in patient mm."""
    from skimage import measure
    verts, faces, _, _ = measure.marching_cubes(mask.astype(np.float32, copy=False), 0.5)
    return ct.index_to_patient(verts), faces


def bench_solve_vs_mc(bset, mask, ct, repeats: int = 7, nu: int = 40, nv: int = 60) -> dict:
    """solve_pde + surface(nu, nv) against marching cubes of the whole mask (paper: 0.66 s vs 874.75 s)."""
    ours, _ = timed(lambda: E.solve_pde(bset).surface(nu, nv), repeats)
    solve_only, _ = timed(lambda: E.solve_pde(bset), repeats)
    caps, _ = timed(lambda: E.solve_pde(bset).surface(nu, nv, caps=True), repeats)
    peer, (verts, faces) = timed(lambda: marching_cubes(mask, ct), max(1, repeats // 2))
    return {"ours": {"name": f"solve_pde (t={bset.patches}) + surface({nu}, {nv})", **ours},
            "ours_solve_only": solve_only, "ours_with_caps": caps,
            "peer": {"name": f"skimage marching_cubes on the {mask.shape} mask", "triangles": int(len(faces)), **peer},
            "speedup": peer["median_s"] / ours["median_s"],
            "paper": {"pde_s": PAPER["pde_seconds"], "mc_s": PAPER["mc_seconds"],
                      "speedup": PAPER["mc_seconds"] / PAPER["pde_seconds"]}}


def bench_surface(head, repeats: int = 15, nu: int = 200, nv: int = 400) -> dict:
    """surface(nu, nv) on a solved head (level of detail by nu, nv alone)."""
    stats, mesh = timed(lambda: head.surface(nu, nv), repeats)
    return {"name": f"PDEHead.surface({nu}, {nv})", "vertices": int(len(mesh.vertices)),
            "quads": int(len(mesh.quads)), **stats}


def bench_w_field(head, ct, repeats: int = 5) -> dict:
    """w_field on the CT's own grid (the 3-D texture of section 4.3.1)."""
    stats, wf = timed(lambda: head.w_field(ct), repeats)
    inside = wf.w <= 1
    return {"name": f"PDEHead.w_field(CT grid {ct.shape})", "inside_voxels": int(inside.sum()), **stats}


def bench_storage(obj, mc_triangles: int) -> dict:
    """Our boundary file against a binary STL of the marching-cubes mesh (84 + 50 bytes per triangle)."""
    data = E.dumps_boundaries(obj)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "head.pdeh"
        E.save_boundaries(obj, path)
        size = path.stat().st_size
        back = E.load_boundaries(path)
    bset = obj.bset if hasattr(obj, "bset") else obj
    head = obj if hasattr(obj, "bset") else E.solve_pde(obj)
    reloaded = E.loads_head(data)
    dist = float(np.linalg.norm(head.surface(100, 200).vertices - reloaded.surface(100, 200).vertices, axis=1).max())
    stl = 84 + 50 * int(mc_triangles)
    return {"ours_bytes": size, "curves": int(bset.curves.shape[0]), "samples": int(bset.samples),
            "curve_max_error_mm": float(np.abs(back.curves - bset.curves).max()),
            "surface_100x200_max_vertex_distance_mm": dist,
            "peer_stl_bytes": stl, "ratio": stl / size,
            "paper": {"ours_kB": PAPER["storage_ours_kB"], "mc_kB": PAPER["storage_mc_kB"]}}


def bench_fidelity(head, mc_verts, mc_faces, samples: int = 100_000) -> dict:
    """Symmetric distance of the open PDE tube (nu = 8t+1, nv = 256) between the lowest and the highest
    curve to the marching-cubes surface triangles whose centroid lies within the z range of the curves
    (:func:`_common.tube_fidelity`; the crown's dome above the top curve has no partner there)."""
    d = tube_fidelity(head, mc_verts, mc_faces, samples, everything=True)
    return {k: d[k] for k in ("mean", "p95", "max", "rms")} | {"a_to_b": d["a_to_b"], "b_to_a": d["b_to_a"]}


def c1_jump(head, nv: int = 256) -> float:
    """Largest relative jump of dX/du across the patch joins (positional conditions give C0 only)."""
    v = 2 * np.pi * np.arange(nv) / nv
    out = 0.0
    for k in range(1, head.patches):
        u, h = k / head.patches, 1e-4
        dl = (head.evaluate(u - 1e-9, v) - head.evaluate(u - h, v)) / h
        dr = (head.evaluate(u + h, v) - head.evaluate(u + 1e-9, v)) / h
        out = max(out, float(np.linalg.norm(dl - dr, axis=1).max() / np.linalg.norm(dl, axis=1).mean()))
    return out


def run(repeats: int = 7) -> dict:
    path = DATA / "cthead_stanford" / "raw16"
    if not path.exists():
        raise SystemExit(f"data not found: {path} (set PDEHEAD_DATA)")
    t0 = time.perf_counter()
    ct = E.load_ct(path, **CTHEAD_RAW16)
    seg = E.segment_head(ct)
    b10 = E.extract_boundaries(seg, patches=10, samples=256)
    b31 = E.extract_boundaries(seg, patches=31, samples=256)
    setup_s = time.perf_counter() - t0
    head = E.solve_pde(b10)
    res: dict[str, Any] = {"dataset": "cthead_stanford raw16", "setup_s": setup_s, "repeats": repeats}
    res["solve_vs_mc"] = bench_solve_vs_mc(b10, seg.mask, ct, repeats)
    res["surface"] = bench_surface(head, max(repeats, 15))
    res["w_field"] = bench_w_field(head, ct, repeats)
    mc_verts, mc_faces = marching_cubes(seg.mask, ct)
    res["storage"] = bench_storage(head, len(mc_faces))
    t_align, aligned = timed(lambda: align_parameterisation(b10), 3)
    res["align_parameterisation_s"] = t_align
    res["fidelity"] = {
        "t10_as_extracted": bench_fidelity(head, mc_verts, mc_faces),
        "t10_aligned": bench_fidelity(E.solve_pde(aligned), mc_verts, mc_faces),
        "t31_as_extracted": bench_fidelity(E.solve_pde(b31), mc_verts, mc_faces),
        "t31_aligned": bench_fidelity(E.solve_pde(align_parameterisation(b31)), mc_verts, mc_faces),
    }
    res["solver"] = {"smoothing": [float(a) for a in head.smoothing], "modes": head.modes,
                     "condition_max": float(head.condition.max()), "lebesgue_max": float(head.lebesgue.max()),
                     "c1_jump": c1_jump(head),
                     "volume_ml": signed_volume(head.surface(200, 400, caps=True)) / 1000.0}
    return res


def table(res: dict) -> str:
    sv, f = res["solve_vs_mc"], res["fidelity"]
    rows = [
        ("solve + surface(40,60), t=10", f"{sv['ours']['median_s'] * 1e3:.2f} ms", "paper 0.66 s"),
        ("  solve only / with caps", f"{sv['ours_solve_only']['median_s'] * 1e3:.2f} / "
                                     f"{sv['ours_with_caps']['median_s'] * 1e3:.2f} ms", ""),
        ("marching cubes (peer, same run)", f"{sv['peer']['median_s'] * 1e3:.1f} ms", "paper 874.75 s"),
        ("speed-up", f"{sv['speedup']:.1f}x", f"target >= {TARGETS['speedup']:g}x, paper 1325x"),
        ("surface(200, 400)", f"{res['surface']['median_s'] * 1e3:.2f} ms",
         f"target <= {TARGETS['surface_200x400_s'] * 1e3:g} ms"),
        ("w_field, CThead grid", f"{res['w_field']['median_s']:.3f} s", f"target <= {TARGETS['w_field_s']:g} s"),
        ("boundary file t=10, M=256", f"{res['storage']['ours_bytes'] / 1000:.1f} kB",
         f"STL of MC {res['storage']['peer_stl_bytes'] / 1e6:.1f} MB ({res['storage']['ratio']:.0f}x); paper 62 kB"),
        ("  reload max vertex distance", f"{res['storage']['surface_100x200_max_vertex_distance_mm']:.4f} mm",
         "target <= 0.05 mm"),
        ("align_parameterisation t=10", f"{res['align_parameterisation_s']['median_s'] * 1e3:.0f} ms", ""),
    ]
    for key, d in f.items():
        rows.append((f"fidelity {key} (mean / p95 / max)", f"{d['mean']:.3f} / {d['p95']:.2f} / {d['max']:.1f} mm", ""))
    s = res["solver"]
    rows.append(
        (
            "solver: cond / Lebesgue / C1 jump",
            f"{s['condition_max']:.0f} / {s['lebesgue_max']:.2f} / {s['c1_jump']:.2f}",
            f"a = {np.mean(s['smoothing']):.4f}, N = {s['modes']}",
        )
    )
    w = max(len(r[0]) for r in rows)
    return "\n".join(f"{a:<{w}}  {b:<28} {c}" for a, b, c in rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", type=Path, default=None, help="write the measurements as JSON here")
    args = ap.parse_args(argv)
    res = run(args.repeats)
    print(table(res))
    if args.json:
        args.json.write_text(json.dumps(res, indent=2, default=float))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
