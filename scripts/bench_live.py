#!/usr/bin/env python3
"""Slider timings of the PDE Head sidebar in real Blender (bpy): is each live change within a frame?

Runs the add-on from this repository's source (as the CLI does), builds a CThead study with the
add-on's defaults (t = 10, surface/solid 120 x 240, nw = 5; no volume), then changes each live
parameter the way the sidebar does (setting the study property, which runs its update callback)
and times the whole callback: the median of ``--repeats`` changes, each to a new value.

Targets (issue 10): a nu/nv change of the surface <= 50 ms; a cutaway (u/v/w range) or nw change of
the solid <= 100 ms, on CThead. A nu/nv change also rebuilds the solid (both share the resolution):
the table lists the surface's own step and the whole callback.

Writes ``docs/benchmarks_live.json`` and its own section ``live-sliders`` of ``docs/benchmarks.md``
(:mod:`md_sections`: the rest of that file belongs to ``scripts/bench.py`` and the other benchmarks).

Usage::

    python3 scripts/bench_live.py                 # CThead, 7 repeats
    python3 scripts/bench_live.py --repeats 3 --datasets cthead ge
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

SECTION = "live-sliders"
SURFACE_TARGET_S = 0.050
SOLID_TARGET_S = 0.100


def _changes():
    """(label, property, value of step i, target, which timing is the target's) for each slider.

    Every step sets a value not used before, as dragging a slider does (no cache can help).
    """
    two_pi = 2 * math.pi
    return [
        ("nu (surface + solid)", "nu", lambda i: 121 + i, SURFACE_TARGET_S, "surface"),
        ("nv (surface + solid)", "nv", lambda i: 241 + i, SURFACE_TARGET_S, "surface"),
        ("nw (solid)", "nw", lambda i: 6 + i, SOLID_TARGET_S, "total"),
        ("v range cutaway (solid)", "v_range", lambda i: (math.pi / 2 + 0.013 * i, two_pi), SOLID_TARGET_S, "total"),
        ("u range cutaway (solid)", "u_range", lambda i: (0.0, 0.8 - 0.011 * i), SOLID_TARGET_S, "total"),
        ("w range cutaway (solid)", "w_range", lambda i: (0.0, 0.8 - 0.011 * i), SOLID_TARGET_S, "total"),
    ]


def _load_options(name: str):
    from _common import CTHEAD_RAW16_OPTIONS, data_path
    if name == "cthead":
        o = CTHEAD_RAW16_OPTIONS
        return dict(directory=str(data_path("cthead_stanford", "raw16")), format='RAW', raw_shape=o["shape"],
                    raw_dtype="i2", byte_order='BIG', use_spacing=True, spacing=o["spacing"],
                    first_slice='SUPERIOR')
    if name == "ge":
        return dict(directory=str(data_path("ct_head_ge_tilt_dicom", "dicom")))
    raise SystemExit(f"unknown dataset {name!r} (cthead, ge)")


def bench_dataset(name: str, repeats: int) -> dict:
    import bpy

    from pdehead_dev.operators import state
    bpy.ops.wm.read_homefile(use_empty=True)
    t0 = time.perf_counter()
    assert bpy.ops.pdehead.run_pipeline(source='FILES', build_volume=False, **_load_options(name)) == {'FINISHED'}
    coll = bpy.context.scene.pdehead.active_study
    s = coll.pdehead
    out = {"pipeline_s": time.perf_counter() - t0, "build_solid_s": state.timings(coll).get("solid"),
           "surface_vertices": len(s.surface_object.data.vertices),
           "solid_vertices": len(s.solid_object.data.vertices), "rows": []}
    for label, prop, values, target, basis in _changes():
        totals, surfaces, solids = [], [], []
        original = getattr(s, prop)
        original = tuple(original) if not isinstance(original, (int, float)) else original
        for i in range(repeats):
            s.timings_json = ""
            t = time.perf_counter()
            setattr(s, prop, values(i))
            totals.append(time.perf_counter() - t)
            if s.last_error:
                raise RuntimeError(f"{label}: {s.last_error}")
            tm = state.timings(coll)
            surfaces.append(tm.get("surface"))
            solids.append(tm.get("solid"))
        setattr(s, prop, original)
        row = {"label": label, "property": prop, "repeats": repeats, "total_s": statistics.median(totals),
               "all_s": totals, "target_s": target, "basis": basis}
        if all(x is not None for x in surfaces):
            row["surface_s"] = statistics.median(surfaces)
        if all(x is not None for x in solids):
            row["solid_s"] = statistics.median(solids)
        measured = row["surface_s"] if basis == "surface" else row["total_s"]
        row["met"] = measured <= target
        out["rows"].append(row)

    # after reopening (new session: nothing in memory): the first cutaway re-reads the CT and tabulates it
    with tempfile.TemporaryDirectory() as tmp:
        blend = os.path.join(tmp, "live.blend")
        bpy.ops.wm.save_as_mainfile(filepath=blend)
        bpy.ops.wm.open_mainfile(filepath=blend)
        state.drop_cache()
        coll = [c for c in bpy.data.collections if c.pdehead.is_study][0]
        s = coll.pdehead
        t = time.perf_counter()
        s.v_range = (math.pi / 2, 2 * math.pi)
        out["first_cutaway_after_reopen_s"] = time.perf_counter() - t
        t = time.perf_counter()
        s.v_range = (math.pi / 3, 2 * math.pi)
        out["second_cutaway_after_reopen_s"] = time.perf_counter() - t
        bpy.ops.wm.read_homefile(use_empty=True)
    return out


def machine() -> dict:
    import numpy as np
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    import bpy
    return {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__, "bpy": bpy.app.version_string,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "load_average": [round(x, 2) for x in load] if load else None}


def markdown(result: dict) -> str:
    m = result["machine"]
    lines = ["## Live sliders in Blender (`scripts/bench_live.py`)", "",
             f"Generated by `python3 scripts/bench_live.py` on {m['date']} (bpy {m['bpy']}, {m['cores']} cores, "
             f"load average at start {m['load_average']}; the machine is shared, timings are wall clock). "
             "Each row: one live parameter set as the sidebar does (its update callback rebuilds the objects), "
             f"median of {result['repeats']} changes, each to a value not used before (as when dragging); add-on defaults "
             "(t = 10, 120 x 240, nw = 5). A nu/nv change rebuilds the surface and the solid: the target is the "
             "surface's step, the whole callback is listed too.", ""]
    for name, d in result["datasets"].items():
        lines += [f"### {name}: surface {d['surface_vertices']} vertices, solid {d['solid_vertices']} vertices",
                  "", "| change | surface step | solid step | whole callback | target | status |",
                  "|---|---|---|---|---|---|"]
        for r in d["rows"]:
            fmt = lambda x: f"{1000 * x:.0f} ms" if x is not None else "-"  # noqa: E731
            lines.append(f"| {r['label']} | {fmt(r.get('surface_s'))} | {fmt(r.get('solid_s'))} | "
                         f"{fmt(r['total_s'])} | <= {1000 * r['target_s']:.0f} ms ({r['basis']}) | "
                         f"{'**met**' if r['met'] else '**NOT met**'} |")
        lines += ["", f"Build Solid in the pipeline (incl. tabulating the CT in (u, v, w) once): "
                      f"{d['build_solid_s']:.2f} s. After reopening the file (nothing in memory) the first cutaway "
                      f"re-reads the CT and tabulates it: {d['first_cutaway_after_reopen_s']:.2f} s; the next one "
                      f"{1000 * d['second_cutaway_after_reopen_s']:.0f} ms.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--datasets", nargs="+", default=["cthead"])
    p.add_argument("--json", type=Path, default=ROOT / "docs" / "benchmarks_live.json")
    p.add_argument("--md", type=Path, default=ROOT / "docs" / "benchmarks.md")
    args = p.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-bench-live-"))
    import pdehead  # the CLI's source registration (package pdehead_dev)
    pdehead.register_addon()
    result = {"command": " ".join(["scripts/bench_live.py", *(argv if argv is not None else sys.argv[1:])]),
              "repeats": args.repeats, "machine": machine(), "datasets": {}}
    for name in args.datasets:
        result["datasets"][name] = bench_dataset(name, args.repeats)
    args.json.write_text(json.dumps(result, indent=1))
    from md_sections import write_section
    write_section(args.md, SECTION, markdown(result))
    for name, d in result["datasets"].items():
        for r in d["rows"]:
            print(f"{name:8s} {r['label']:28s} total {1000 * r['total_s']:6.1f} ms  "
                  f"surface {1000 * (r.get('surface_s') or 0):5.1f} ms  solid {1000 * (r.get('solid_s') or 0):5.1f} ms"
                  f"  {'met' if r['met'] else 'NOT met'}")
    return 0 if all(r["met"] for d in result["datasets"].values() for r in d["rows"]) else 1


if __name__ == "__main__":
    sys.exit(main())
