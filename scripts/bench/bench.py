#!/usr/bin/env python3
"""PDE Head benchmarks against their peers; regenerates docs/benchmarks.md and docs/benchmarks.json.

Regenerate the committed tables (full run, median of 5, several minutes on 2 cores)::

    python3 scripts/bench/bench.py

Other uses::

    python3 scripts/bench/bench.py --quick                 # < 1 min: phantom + CThead, fewer repeats, slow peers subset
    python3 scripts/bench/bench.py --repeats 1 --datasets cthead --stages seg,surface --out /tmp/b.json --md /tmp/b.md
    PDEHEAD_DATA=/path/to/data python3 scripts/bench/bench.py   # data folder (default ../shared/data beside the repo)

The measurements themselves are the other helpers' importable functions
(``scripts/bench/bench_segmentation.py``: ``measure_segmentation``, ``measure_peer``,
``reference_for``; ``scripts/bench/bench_pde.py``: ``bench_solve_vs_mc``, ``bench_surface``,
``bench_w_field``, ``bench_storage``, ``bench_fidelity``, ``marching_cubes``); this script
adds the Blender builds, the STL, the VDB, memory, the data sets and the report.

Every speed row is the MEDIAN over ``--repeats`` runs of ours and of the peer in the same
process and run: segmentation (``segment_head`` against ``skimage.segmentation.chan_vese``
slice by slice on the same slices, both scored by Jaccard against the independent
threshold reference of :mod:`pdehead_addon.validation.metrics`), boundary extraction, PDE solve +
surface against ``skimage.measure.marching_cubes`` on the same mask (each INCLUDING the
build of the Blender mesh with the add-on's ``build_mesh_object``, reported separately
and together), storage (our boundary file against a binary STL of the marching-cubes
mesh), the PDE-to-marching-cubes surface distance for t in {4, 5, 6, 10, 14, 31}
(paper Fig. 12), the uv-resolution series of Fig. 13, the w-field and its VDB, and peak
memory. Blender (``bpy``) is imported in this process; the add-on is loaded from this
repository as package ``pdehead_dev`` (``_common.load_addon``, no zip).

Memory is reported two ways, both per stage: the process RSS high-water mark
(``VmHWM`` of /proc/self/status after resetting it through /proc/self/clear_refs),
as the increase over the RSS at the stage's start; and, in full runs, the peak of
Python/numpy allocations under ``tracemalloc`` in a separate untimed pass. The
512 x 512 x 300 target is measured in a fresh subprocess (phantom written as DICOM,
then load -> segment -> boundaries -> PDE -> w-field), by the same per-stage RSS
high-water mark; the largest of them is the pipeline's peak.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import gc
import importlib
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
import traceback
import tracemalloc
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
for _p in (str(ROOT), str(ROOT / "scripts")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

DOCS = ROOT / "docs"

import _common  # noqa: E402  (data sets and their loader options, the paper's numbers, timing, dev shim)
import pdehead_addon as E  # noqa: E402
from _common import (  # noqa: E402,F401  # noqa: E402,F401
    CTHEAD_RAW16_OPTIONS,
    CTHEAD_TIFF8_OPTIONS,
    PAPER,
    blender,
    boundaries,
    error_text,
    marching_cubes_mesh,
    median,
    remove_object,
    timed,
)
from pdehead_addon import defaults as D  # noqa: E402

DATA = _common.SHARED_DATA

# ----------------------------------------------------------------------------- targets (from the issues)
T_SEG_SECONDS = 2.0          # segmentation of CThead
T_SEG_SPEEDUP = 5.0          # against skimage chan_vese per slice, at equal or better Jaccard
T_SURFACE_SPEEDUP = 100.0    # solve + surface(40, 60), t = 10, against marching cubes
T_SURFACE_200_400 = 0.016    # s
T_WFIELD_SECONDS = 1.0       # w-field on the CThead grid
T_STORAGE_BYTES = 16 * 1024  # t = 10, M = 256
T_FID_T10_MEAN, T_FID_T10_P95, T_FID_T31_MEAN = 1.0, 3.0, 0.6  # mm
T_MEMORY_512_BYTES = 4 * 1024 ** 3

FIDELITY_T = (4, 5, 6, 10, 14, 31)
#: (nu, nv) of the paper's Fig. 13 (u=10..80 at v=40, then v=10..80 at u=60), plus (200, 400).
UV_SERIES = ((10, 40), (20, 40), (40, 40), (60, 40), (80, 40), (60, 10), (60, 20), (60, 60), (60, 80),
             (200, 400))
PEER_SUBSET_SLICES = 12     # chan_vese slices on the 512 x 512 GE and on the tiff8 copy of CThead
STAGES = ("load", "seg", "boundaries", "surface", "storage", "fidelity", "uv", "wfield", "memory")


# ============================================================================= small utilities
def _status_kb(key: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_hwm() -> bool:
    """Reset the RSS high-water mark (Linux >= 4.0: write 5 to /proc/self/clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


class RSSProbe:
    """RSS high-water mark of a stage: ``with RSSProbe() as p: ...; p.result``."""

    def __enter__(self):
        gc.collect()
        self.reset = _reset_hwm()
        self.start_kb = _status_kb("VmRSS")
        return self

    def __exit__(self, *exc):
        hwm = _status_kb("VmHWM")
        self.result = None
        if self.reset and hwm is not None and self.start_kb is not None:
            self.result = {"rss_start_MB": self.start_kb / 1024, "rss_hwm_MB": hwm / 1024,
                           "rss_increase_MB": max(0, hwm - self.start_kb) / 1024}
        return False


def tracemalloc_peak(fn: Callable[[], Any]) -> float:
    """Peak MB of Python/numpy allocations while ``fn`` runs (numpy reports to tracemalloc)."""
    gc.collect()
    tracemalloc.start()
    tracemalloc.reset_peak()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 1024 ** 2


def machine_info() -> dict[str, Any]:
    cpu = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import scipy
    import skimage
    info = {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "scikit-image": skimage.__version__,
            "platform": platform.platform(),
            "date": _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z"),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
    try:
        mem_kb = int(next(line.split()[1] for line in open("/proc/meminfo") if line.startswith("MemTotal")))
        info["memory_GB"] = round(mem_kb / 1024 ** 2, 1)
    except Exception:
        pass
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        info["git"] = commit + ("+uncommitted" if dirty else "")
    except Exception:
        pass
    return info


# ============================================================================= Blender layer (dev shim)
def blender_build_time(mesh, collection, repeats: int, name: str) -> dict[str, Any]:
    """Median time of ``build_mesh_object(mesh, collection, name)`` (each built object is removed untimed)."""
    objects = blender()["objects"]
    runs = []
    remove_object(objects.build_mesh_object(mesh, collection, name))  # warm-up, untimed
    gc.collect()
    for _ in range(max(1, repeats)):
        gc.disable()
        try:
            t0 = time.perf_counter()
            obj = objects.build_mesh_object(mesh, collection, name)
            runs.append(time.perf_counter() - t0)
        finally:
            gc.enable()
        n_poly = len(obj.data.polygons)
        remove_object(obj)
    return {"median_s": median(runs), "min_s": float(min(runs)), "runs_s": runs, "polygons": n_poly}


# ============================================================================= peers
FIDELITY_DEFINITION = ("open PDE tube (caps=False, nu = 8t+1, nv = 256) against the marching-cubes surface of the"
                       " same mask restricted to the triangles whose centroid lies between the lowest and the"
                       " highest boundary curve (the z range the PDE surface covers)")


#: The add-on's default slice selection (pdehead_addon/defaults.py).
SELECTION = D.SELECTION.default


def _stats(d: dict) -> dict:
    """The timing fields of a bench_pde result."""
    return {k: d[k] for k in ("median_s", "min_s", "runs_s") if k in d}


def _segbench():
    """The segmentation helper's importable measurement functions (scripts/bench/bench_segmentation.py)."""
    return importlib.import_module("bench_segmentation")


def _pdebench():
    """The PDE helper's importable measurement functions (scripts/bench/bench_pde.py)."""
    return importlib.import_module("bench_pde")


def reference_mask(key: str, ct, phantom=None) -> tuple[np.ndarray | None, str]:
    """The reference head mask of a data set and its description (bench_segmentation.reference_for)."""
    if phantom is not None:
        return phantom.head_mask, "exact phantom truth (Phantom.head_mask)"
    return _segbench().reference_for(key, ct)


# ============================================================================= data sets
def datasets(args) -> list[dict[str, Any]]:
    sets = [
        {"key": "phantom", "label": "phantom (synthetic head, 100x128x128)", "kind": "phantom", "full": True},
        {"key": "cthead", "label": "CThead raw16 (Stanford, 113x256x256, 2x1x1 mm)", "kind": "ct", "full": True,
         "path": DATA / "cthead_stanford" / "raw16", "options": CTHEAD_RAW16_OPTIONS},
        {"key": "cthead_tiff8", "label": "CThead tiff8 (same subject, slices 1-99, 8 bit)", "kind": "ct",
         "full": False, "path": DATA / "cthead_stanford" / "tiff8", "options": CTHEAD_TIFF8_OPTIONS},
        {"key": "ge", "label": "GE DICOM (28 tilted slices, 512x512 HU)", "kind": "ct", "full": True,
         "path": DATA / "ct_head_ge_tilt_dicom" / "dicom", "options": {}},
        {"key": "mri", "label": "MRI ch2 (MRI, not CT: load/segmentation only)", "kind": "mri", "full": False,
         "path": DATA / "mri_colin27_ch2" / "ch2.nii.gz", "options": {}},
    ]
    wanted = args.datasets.split(",") if args.datasets else (
        ["phantom", "cthead"] if args.quick else [s["key"] for s in sets])
    return [s for s in sets if s["key"] in wanted]


def load_dataset(ds):
    if ds["kind"] == "phantom":
        ph = E.make_phantom()
        return ph.ct, ph
    return E.load_ct(ds["path"], **ds["options"]), None


# ============================================================================= the benchmark
class Bench:
    def __init__(self, args):
        self.args = args
        self.quick = args.quick
        self.repeats = args.repeats if args.repeats else (2 if args.quick else 5)
        self.stages = set(args.stages.split(",")) if args.stages else set(STAGES)
        self.use_blender = not args.no_blender
        self.tmp = Path(tempfile.mkdtemp(prefix="pdehead-bench-"))
        self.out: dict[str, Any] = {
            "command": "python3 scripts/bench/bench.py" + (" " + " ".join(sys.argv[1:]) if sys.argv[1:] else ""),
            "mode": "quick" if self.quick else "full", "repeats": self.repeats, "machine": machine_info(),
            "data_folder": str(DATA), "datasets": {}, "notes": [],
        }

    def note(self, text: str) -> None:
        if text not in self.out["notes"]:
            self.out["notes"].append(text)
        print("  note:", text, flush=True)

    def stage(self, res: dict, name: str, fn: Callable[[], dict]) -> dict | None:
        """Run one stage, store its dict (or its error) under res[name]."""
        t0 = time.perf_counter()
        print(f"  [{name}] ...", flush=True)
        try:
            with RSSProbe() as probe:
                value = fn()
            if isinstance(value, dict) and probe.result is not None:
                value.setdefault("memory_rss", probe.result)
            res[name] = value
        except Exception as exc:  # one failing stage must not stop the others
            res[name] = {"error": error_text(exc)}
            if not isinstance(exc, (ImportError, E.PDEHeadError)):
                traceback.print_exc()
            value = None
        error = f"  ERROR {res[name]['error']}" if value is None else ""
        print(f"  [{name}] {time.perf_counter() - t0:.1f} s" + error,
              flush=True)
        return value

    # ------------------------------------------------------------------ per data set
    def run_dataset(self, ds) -> None:
        key = ds["key"]
        print(f"== {ds['label']}", flush=True)
        res: dict[str, Any] = {"label": ds["label"], "kind": ds["kind"]}
        if ds.get("path") is not None:
            res["path"] = str(ds["path"])
            if not Path(ds["path"]).exists():
                res["error"] = f"data not found: {ds['path']}"
                self.out["datasets"][key] = res
                print("  missing:", ds["path"])
                return
        self.out["datasets"][key] = res
        st = {}  # shared state between stages

        def load():
            stats, (ct, ph) = timed(lambda: load_dataset(ds), self.repeats if ds["kind"] != "phantom" else 1)
            st["ct"], st["phantom"] = ct, ph
            out = {"time": stats, "shape": list(ct.shape), "spacing_mm": list(ct.spacing),
                   "modality": ct.meta.get("modality"), "warnings": [str(w) for w in ct.meta.get("warnings", [])]}
            if ds["kind"] == "phantom":
                out["what"] = "make_phantom() (generation, not a file load)"
            return out

        if self.stage(res, "load", load) is None:
            return
        if "seg" in self.stages:
            self.stage(res, "segmentation", lambda: self.segmentation(key, st, ds))
        if "seg" not in st:
            return
        if not ds["full"]:
            return
        if "boundaries" in self.stages or "surface" in self.stages:
            self.stage(res, "boundaries", lambda: self.boundaries(st))
        if "bset" not in st:
            return
        # (stage flag, result name, the data sets it runs on (None: all), what it runs)
        later = [("surface", "surface", None, lambda: self.surface(key, st)),
                 ("storage", "storage", None, lambda: self.storage(st)),
                 ("fidelity", "fidelity", ("cthead", "phantom", "ge"), lambda: self.fidelity(key, st)),
                 ("uv", "uv", ("cthead",), lambda: self.uv_series(st)),
                 ("wfield", "wfield", ("cthead", "phantom"), lambda: self.wfield(st)),
                 ("memory", "memory_tracemalloc", () if self.quick else ("cthead",), lambda: self.memory_pass(st))]
        for flag, name, keys, run in later:
            if flag in self.stages and (keys is None or key in keys):
                self.stage(res, name, run)
        for k in ("seg", "bset", "head", "mc", "ct"):
            st.pop(k, None)
        gc.collect()

    # ------------------------------------------------------------------ segmentation
    def segmentation(self, key, st, ds) -> dict:
        """bench_segmentation.measure_segmentation (ours) and .measure_peer (skimage chan_vese per slice)."""
        from pdehead_addon.validation.metrics import head_slices, slice_jaccard_on_head
        sb = _segbench()
        ct, ph = st["ct"], st["phantom"]
        ref, ref_desc = (None, "none (MRI)") if ds["kind"] == "mri" else reference_mask(key, ct, ph)
        with RSSProbe() as probe:
            ours = sb.measure_segmentation(ct, self.repeats, ref)
        seg = ours.pop("_segmentation")
        st["seg"] = seg
        ours.update(time=_stats(ours), voxels=int(np.count_nonzero(seg.mask)), memory_rss=probe.result)
        out: dict[str, Any] = {"via": "bench_segmentation.measure_segmentation / measure_peer", "ours": ours}
        if ds["kind"] == "mri":
            out["note"] = "MRI, not CT: graceful-degradation check only (no reference, no peer)"
            out["ours"]["mask_fraction"] = float(np.count_nonzero(seg.mask)) / seg.mask.size
            out["ours"]["modality"] = ct.meta.get("modality")
            return out
        if ref is None:
            return out
        out["reference"] = ref_desc
        hs = head_slices(ref)
        per = slice_jaccard_on_head(seg.mask, ref)
        out["head_slices"] = len(hs)
        out["per_slice_jaccard"] = {"slices": [int(k) for k in hs], "ours": [float(x) for x in per]}

        # The peer costs 0.3-7 s per slice: it runs ONCE on each of its slices (a median over >= 5
        # slice runs), on every head slice where that takes a few minutes at most, else on an evenly
        # spaced subset whose mean per-slice time is extrapolated to all head slices (labelled).
        n_peer = 3 if self.quick else (len(hs) if key in ("cthead", "phantom") else PEER_SUBSET_SLICES)
        pick = np.linspace(0, len(hs) - 1, min(n_peer, len(hs))).round().astype(int)
        peer_slices = hs[pick]
        gc.collect()
        peer = sb.measure_peer(ct, ref, seg.meta.get("window"), slices=peer_slices)
        subset = len(peer_slices) < len(hs)
        per_slice_mean = peer["total_s"] / len(peer_slices)
        peer.update(slice_indices=[int(k) for k in peer_slices], subset=bool(subset),
                    per_slice_s=per_slice_mean, all_head_slices_s=per_slice_mean * len(hs),
                    ours_slice_jaccard_mean_same_slices=float(per[pick].mean()),
                    ours_slice_jaccard_min_same_slices=float(per[pick].min()))
        if subset:  # the clean-up is 3-D (largest connected component): meaningless on a few separate slices
            peer["cleaned_valid"] = False
        out["peer"] = peer
        # same work: the peer on every head slice (measured, or extrapolated from the subset) vs our whole volume
        out["ratio"] = peer["all_head_slices_s"] / ours["median_s"]
        return out

    # ------------------------------------------------------------------ boundaries
    def boundaries(self, st) -> dict:
        seg = st["seg"]
        # t = 10 as in the paper; fewer patches where the scan has too few usable slices (the GE series),
        # like the add-on does
        t_max = E.max_patches(seg)
        t = min(10, t_max) if t_max >= 1 else 10
        refused = f"the scan allows t <= {t_max}" if t < 10 else None
        stats, bset = timed(lambda: boundaries(seg, t, 256), self.repeats)
        st["bset"], st["t"] = bset, t
        out = {"time": stats, "patches": bset.patches, "samples": bset.samples,
               "parameterisation": bset.meta.get("parameterisation"), "selection": SELECTION,
               "slice_indices": [int(k) for k in bset.slice_indices]}
        if refused:
            out["note"] = f"t = 10 refused ({refused}); using t = {t}"
        return out

    # ------------------------------------------------------------------ PDE surface vs marching cubes
    def surface(self, key, st) -> dict:
        """bench_pde.bench_solve_vs_mc (engine, same run) plus the Blender mesh builds of both results."""
        pb = _pdebench()
        ct, seg, bset = st["ct"], st["seg"], st["bset"]
        nu, nv = 40, 60
        # bench_solve_vs_mc runs the peer max(1, repeats // 2) times: 2x repeats gives it `repeats` runs
        r = pb.bench_solve_vs_mc(bset, seg.mask, ct, repeats=2 * self.repeats, nu=nu, nv=nv)
        with RSSProbe() as probe:
            head = E.solve_pde(bset)
            mesh = head.surface(nu, nv, caps=True)
        with RSSProbe() as probe_mc:
            mc = marching_cubes_mesh(seg.mask, ct)
        st["head"], st["mc"] = head, mc
        out: dict[str, Any] = {
            "via": "bench_pde.bench_solve_vs_mc",
            "ours": {"name": r["ours"]["name"], "engine": _stats(r["ours"]), "solve_only": r["ours_solve_only"],
                     "engine_with_caps": r["ours_with_caps"], "vertices": len(mesh.vertices),
                     "faces": mesh.face_count, "memory_rss": probe.result},
            "peer": {"name": r["peer"]["name"], "engine": _stats(r["peer"]), "vertices": len(mc.vertices),
                     "faces": mc.face_count, "slices_used": int(seg.mask.shape[0]), "memory_rss": probe_mc.result},
            "ratio_engine": r["speedup"], "paper": r.get("paper"),
        }
        if self.use_blender:
            bl = blender()
            coll = bl["objects"].study_collection(f"bench {key}")
            b_ours = blender_build_time(mesh, coll, self.repeats, "bench PDE surface")
            b_mc = blender_build_time(mc, coll, self.repeats, "bench MC surface")
            out["ours"]["blender"] = b_ours
            out["peer"]["blender"] = b_mc
            # together = engine (the capped surface the add-on builds) + Blender build, sum of the medians
            out["ours"]["total_median_s"] = r["ours_with_caps"]["median_s"] + b_ours["median_s"]
            out["peer"]["total_median_s"] = r["peer"]["median_s"] + b_mc["median_s"]
            out["ratio_total"] = out["peer"]["total_median_s"] / out["ours"]["total_median_s"]
            out["blender_version"] = bl["version"]
        return out

    # ------------------------------------------------------------------ storage
    def storage(self, st) -> dict:
        """bench_pde.bench_storage, plus the STL of the peer actually written (binary, by export.write_stl)."""
        pb = _pdebench()
        head, mc = st["head"], st["mc"]
        r = pb.bench_storage(head, len(mc.triangles))
        stl = self.tmp / "mc.stl"
        from pdehead_addon.io.export import write_stl

        def write() -> int:
            write_stl(mc, stl, name="PDE Head benchmark: marching cubes surface")
            return os.path.getsize(stl)
        s_stl, nbytes = timed(write, 1)
        if nbytes != r["peer_stl_bytes"]:
            raise RuntimeError(f"STL size {nbytes} != 84 + 50 x triangles = {r['peer_stl_bytes']}")
        bset = head.bset
        return {"via": "bench_pde.bench_storage",
                "ours": {"name": f"save_boundaries (t={bset.patches}, M={bset.samples})", "bytes": r["ours_bytes"],
                         "roundtrip_max_error_mm": r["curve_max_error_mm"],
                         "reload_surface_max_vertex_distance_mm": r["surface_100x200_max_vertex_distance_mm"]},
                "peer": {"name": "binary STL of the marching-cubes mesh (written)", "bytes": nbytes,
                         "triangles": int(len(mc.triangles)), "write": s_stl},
                "ratio": nbytes / r["ours_bytes"], "paper": r["paper"]}

    # ------------------------------------------------------------------ fidelity (Fig. 12 in numbers)
    def fidelity(self, key, st) -> dict:
        """bench_pde.bench_fidelity for each t (boundaries as the add-on makes them)."""
        pb = _pdebench()
        seg, mc = st["seg"], st.get("mc")
        if mc is None:
            mc = marching_cubes_mesh(seg.mask, st["ct"])
        ts = (st.get("t", 10),) if (self.quick or key != "cthead") else FIDELITY_T
        samples = 20_000 if self.quick else 100_000
        out: dict[str, Any] = {"reference": FIDELITY_DEFINITION, "samples_per_surface": samples, "series": [],
                               "via": "bench_pde.bench_fidelity"}
        out["selection"] = SELECTION
        for t in ts:
            row: dict[str, Any] = {"t": t}
            # the add-on's default selection (the targets' numbers) and the paper's evenly spaced slices
            for selection, prefix in ((SELECTION, ""), ("uniform", "uniform_")):
                if prefix and (self.quick or selection == SELECTION):
                    continue
                try:
                    head = E.solve_pde(boundaries(seg, t, 256, selection))
                    d = pb.bench_fidelity(head, mc.vertices, mc.triangles, samples=samples)
                    row.update({prefix + k: d[k] for k in ("mean", "p95", "max", "rms")})
                    row[prefix + "pde_to_mc"] = d["a_to_b"]
                    row[prefix + "mc_to_pde"] = d["b_to_a"]
                except Exception as exc:
                    row[prefix + "error"] = error_text(exc)
            row["slices_used"] = 3 * t + 1
            out["series"].append(row)
            print(f"    t={t}: " + ", ".join(f"{k} {row[k]:.3f}" for k in row if k.split("_")[-1] in ("mean", "p95"))
                  + (row.get("error") or ""), flush=True)
        return out

    # ------------------------------------------------------------------ uv series (Fig. 13)
    def uv_series(self, st) -> dict:
        """bench_pde.bench_surface per (nu, nv) (open tube), the capped surface, and its Blender build."""
        pb = _pdebench()
        head = st.get("head") or E.solve_pde(st["bset"])
        rows = []
        coll = blender()["objects"].study_collection("bench uv") if self.use_blender else None
        reps = max(self.repeats, 5)  # milliseconds each: always at least 5
        for nu, nv in UV_SERIES:
            r = pb.bench_surface(head, reps, nu, nv)
            s_caps, mesh = timed(lambda nu=nu, nv=nv: head.surface(nu, nv, caps=True), reps, warmup=True)
            row = {"nu": nu, "nv": nv, "engine": _stats(r), "engine_with_caps": s_caps,
                   "vertices": int(r["vertices"])}
            if coll is not None:
                b = blender_build_time(mesh, coll, reps, f"bench uv {nu}x{nv}")
                row["blender"] = b
                row["total_median_s"] = s_caps["median_s"] + b["median_s"]
            rows.append(row)
        return {"rows": rows, "repeats": reps, "via": "bench_pde.bench_surface"}

    # ------------------------------------------------------------------ w-field and VDB
    def wfield(self, st) -> dict:
        """bench_pde.bench_w_field on the CT grid, then the add-on's write_vdb of that w-field."""
        pb = _pdebench()
        ct = st["ct"]
        head = st.get("head") or E.solve_pde(st["bset"])
        with RSSProbe() as probe:
            r = pb.bench_w_field(head, ct, self.repeats)
        out: dict[str, Any] = {"via": "bench_pde.bench_w_field",
                               "ours": {"name": r["name"], "time": _stats(r), "grid": list(ct.shape),
                                        "inside_voxels": r["inside_voxels"], "memory_rss": probe.result}}
        if self.use_blender:
            wf = head.w_field(ct)
            vol = blender()["vdb_grids"]
            window = E.core.ct_volume.intensity_window(ct)
            path = self.tmp / "bench.vdb"
            s_vdb, _ = timed(lambda: vol.write_vdb(wf, path, window, ct=ct), self.repeats, warmup=True)
            out["vdb"] = {"name": "operators/volume/vdb_grids.write_vdb (grids w, intensity, ct)", "time": s_vdb,
                          "bytes": path.stat().st_size}
        return out

    # ------------------------------------------------------------------ tracemalloc pass
    def memory_pass(self, st) -> dict:
        ct = st["ct"]
        out = {"what": "peak of Python/numpy allocations (tracemalloc), one untimed pass per stage, MB"}
        seg_box = {}
        out["segmentation_MB"] = tracemalloc_peak(lambda: seg_box.setdefault("s", E.segment_head(ct)))
        seg = seg_box["s"]
        out["boundaries_MB"] = tracemalloc_peak(lambda: seg_box.setdefault("b", boundaries(seg)))
        bset = seg_box["b"]
        out["solve_surface_MB"] = tracemalloc_peak(lambda: E.solve_pde(bset).surface(40, 60, caps=True))
        out["marching_cubes_MB"] = tracemalloc_peak(lambda: marching_cubes_mesh(seg.mask, ct))
        head = E.solve_pde(bset)
        try:
            out["w_field_MB"] = tracemalloc_peak(lambda: head.w_field(ct, ct=ct))
        except Exception as exc:
            out["w_field_MB"] = None
            out["w_field_error"] = error_text(exc)
        return out

    # ------------------------------------------------------------------ 512 x 512 x 300
    def memory_512(self) -> None:
        print("== peak memory, 512 x 512 x 300 (subprocess)", flush=True)
        cmd = [sys.executable, str(Path(__file__).resolve()), "--memory-probe", "300,512,512"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
        res: dict[str, Any] = {"command": " ".join(cmd[1:]), "wall_s": time.perf_counter() - t0}
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
        if proc.returncode == 0 and lines:
            res.update(json.loads(lines[-1]))
        else:
            res["error"] = (proc.stderr.strip().splitlines() or ["failed"])[-1]
        self.out["memory_512"] = res
        print("  ", res, flush=True)

    # ------------------------------------------------------------------ run all
    def run(self) -> dict:
        t0 = time.perf_counter()
        if self.use_blender:
            bl = blender()
            self.out["machine"]["bpy"] = bl["version"]
        for ds in datasets(self.args):
            self.run_dataset(ds)
        if "memory" in self.stages and not self.quick:
            self.memory_512()
        if self.quick:
            self.note("QUICK mode: phantom + CThead only (unless --datasets), fewer repeats, the chan_vese peer on "
                      "3 head slices once "
                      "(its whole-volume time extrapolated per slice), fidelity for t=10 only with 20k samples, "
                      "no tracemalloc pass and no 512x512x300 memory run.")
        self.out["targets"] = targets(self.out)
        self.out["total_s"] = time.perf_counter() - t0
        return self.out


# ============================================================================= memory probe (subprocess)
def memory_probe(shape_text: str) -> None:
    """Fresh process: phantom of `shape` written as DICOM, then the pipeline; prints one JSON line."""
    shape = tuple(int(s) for s in shape_text.split(","))
    out: dict[str, Any] = {"shape": list(shape), "what": "process RSS high-water mark (VmHWM, reset before each stage)"}
    stages: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="pdehead-mem-") as tmp:
        ph = E.make_phantom(shape=shape)
        E.validation.write_dicom_series(ph.ct, Path(tmp) / "dicom")
        del ph
        gc.collect()
        # before the first reset: the high-water mark of making and writing the phantom (not the pipeline)
        out["phantom_generation_hwm_MB"] = (_status_kb("VmHWM") or 0) / 1024
        base = _status_kb("VmRSS")

        def step(name, fn):
            with RSSProbe() as p:
                t0 = time.perf_counter()
                r = fn()
                dt = time.perf_counter() - t0
            stages[name] = dict(p.result or {}, seconds=dt)
            return r

        ct = step("load", lambda: E.load_ct(Path(tmp) / "dicom"))
        seg = step("segment", lambda: E.segment_head(ct))
        bset = step("boundaries", lambda: boundaries(seg, 10, 256))
        head = step("solve_surface", lambda: (lambda h: (h.surface(200, 400, caps=True), h)[1])(E.solve_pde(bset)))
        try:
            step("w_field", lambda: head.w_field(ct, ct=ct))
        except Exception as exc:
            stages["w_field"] = {"error": error_text(exc)}
    out["stages"] = stages
    out["baseline_rss_MB"] = (base or 0) / 1024
    out["peak_rss_MB"] = max([s.get("rss_hwm_MB", 0) for s in stages.values()] or [0])
    print(json.dumps(out))


# ============================================================================= targets and markdown
def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _segmentation_targets(seg: dict | None, add) -> None:
    """The segmentation's rows of :func:`targets` (its time and the speed-up over the per-slice peer)."""
    if seg and "ours" in seg:
        t = seg["ours"]["time"]["median_s"]
        add("segmentation CThead, time", f"<= {T_SEG_SECONDS} s", f"{t:.2f} s", t <= T_SEG_SECONDS)
        if "peer" in seg:
            r = seg["ratio"]
            pr = seg["peer"]
            # the peer's better Jaccard: raw, or after our own clean-up
            jp = max(pr["slice_jaccard_mean_raw"],
                     pr["slice_jaccard_mean_cleaned"] if pr.get("cleaned_valid", True) else 0.0)
            jo_same = pr["ours_slice_jaccard_mean_same_slices"]
            add("segmentation CThead vs skimage chan_vese per slice",
                f">= {T_SEG_SPEEDUP:g}x faster at equal or better Jaccard",
                f"{r:.1f}x; mean slice Jaccard ours {jo_same:.4f} vs peer {jp:.4f} (same slices, peer's best of"
                f" raw {pr['slice_jaccard_mean_raw']:.4f} / with our clean-up "
                + (f"{pr['slice_jaccard_mean_cleaned']:.4f})" if pr.get("cleaned_valid", True) else "n/a)"),
                r >= T_SEG_SPEEDUP and jo_same >= jp - 1e-9,
                f"peer measured on a {pr['slices']}-slice subset, extrapolated" if pr["subset"] else "")
    elif seg:
        add("segmentation CThead", f"<= {T_SEG_SECONDS} s", seg.get("error", "?"), None)


def targets(out: dict) -> list[dict[str, Any]]:
    ds = out["datasets"]
    rows = []

    def add(name, target, measured, met, note=""):
        rows.append({"name": name, "target": target, "measured": measured,
                     "met": None if met is None else bool(met), "note": note})

    _segmentation_targets(_get(ds, "cthead", "segmentation"), add)
    surf = _get(ds, "cthead", "surface")
    if surf and "ours" in surf:
        r = surf.get("ratio_total", surf["ratio_engine"])
        add("solve + surface(40,60), t=10, vs marching cubes, each incl. its Blender mesh build",
            f">= {T_SURFACE_SPEEDUP:g}x", f"{r:.0f}x (engine only {surf['ratio_engine']:.0f}x)",
            r >= T_SURFACE_SPEEDUP)
    uv = _get(ds, "cthead", "uv")
    if uv and "rows" in uv:
        row = next((r for r in uv["rows"] if (r["nu"], r["nv"]) == (200, 400)), None)
        if row:
            t = row["engine"]["median_s"]
            add("surface(200,400), engine", f"<= {T_SURFACE_200_400 * 1000:g} ms", f"{t * 1000:.1f} ms",
                t <= T_SURFACE_200_400)
    wf = _get(ds, "cthead", "wfield")
    if wf and "ours" in wf:
        t = wf["ours"]["time"]["median_s"]
        add("w_field on the CThead grid", f"<= {T_WFIELD_SECONDS:g} s", f"{t:.2f} s", t <= T_WFIELD_SECONDS)
    elif wf:
        add("w_field on the CThead grid", f"<= {T_WFIELD_SECONDS:g} s", wf.get("error", "?"), None)
    sto = _get(ds, "cthead", "storage")
    if sto and "ours" in sto:
        b = sto["ours"]["bytes"]
        add("storage, t=10, M=256", f"<= {T_STORAGE_BYTES // 1024} kB", f"{b / 1024:.1f} kB",
            b <= T_STORAGE_BYTES)
    elif sto:
        add("storage, t=10, M=256", f"<= {T_STORAGE_BYTES // 1024} kB", sto.get("error", "?"), None)
    fid = _get(ds, "cthead", "fidelity")
    if fid and "series" in fid:
        by_t = {r["t"]: r for r in fid["series"] if "mean" in r}
        if 10 in by_t:
            r = by_t[10]
            add("fidelity t=10 (PDE vs marching cubes)", f"mean <= {T_FID_T10_MEAN} mm, p95 <= {T_FID_T10_P95} mm",
                f"mean {r['mean']:.2f} mm, p95 {r['p95']:.2f} mm",
                r["mean"] <= T_FID_T10_MEAN and r["p95"] <= T_FID_T10_P95)
        if 31 in by_t:
            r = by_t[31]
            add("fidelity t=31", f"mean <= {T_FID_T31_MEAN} mm", f"mean {r['mean']:.2f} mm",
                r["mean"] <= T_FID_T31_MEAN)
    mem = out.get("memory_512")
    if mem and "peak_rss_MB" in mem:
        p = mem["peak_rss_MB"]
        add("peak memory, 512x512x300 volume (RSS high-water, load..w_field)", "<= 4 GB",
            f"{p / 1024:.2f} GB", p * 1024 ** 2 <= T_MEMORY_512_BYTES)
    elif mem:
        add("peak memory, 512x512x300 volume", "<= 4 GB", mem.get("error", "?"), None)
    return rows


def _ms(s):
    return "-" if s is None else (f"{s * 1000:.1f} ms" if s < 1 else f"{s:.2f} s")


def _met(m):
    return "n/a" if m is None else ("**met**" if m else "**NOT met**")


def markdown(out: dict) -> str:
    L = _md_header(out) + _md_targets(out) + _md_speed(out["datasets"]) + _md_storage(out["datasets"])
    L += _md_fidelity(out["datasets"]) + _md_uv(out["datasets"]) + _md_memory(out)
    L.append(f"Total benchmark wall time: {out.get('total_s', 0):.0f} s.")
    return "\n".join(L) + "\n"


def _md_header(out: dict) -> list[str]:
    """The title, the machine, the notes and the peers."""
    m = out["machine"]
    L = ["# PDE Head benchmarks", "",
         f"Generated by `{out['command']}` ({out['mode']} mode, median of {out['repeats']} runs"
         " unless a row says otherwise). Do not edit by hand: rerun `python3 scripts/bench/bench.py`"
         " (full; `--quick` for a < 1 min check). Raw numbers: `docs/benchmarks.json`.", "",
         "## Machine", "",
         "| | |", "|---|---|",
         f"| CPU | {m.get('cpu')} ({m.get('cores')} cores visible) |",
         f"| memory | {m.get('memory_GB', '?')} GB |",
         f"| Python | {m.get('python')} |",
         f"| numpy / scipy / scikit-image | {m.get('numpy')} / {m.get('scipy')} / {m.get('scikit-image')} |",
         f"| Blender (bpy) | {m.get('bpy', 'not used')} |",
         f"| date | {m.get('date')} |",
         f"| commit | {m.get('git', '?')} |",
         f"| load average at start | {', '.join(f'{x:.1f}' for x in (m.get('load_average') or []))} "
         "(the machine is shared; timings are wall clock) |", ""]
    if out.get("notes"):
        L += ["**Notes:** " + " ".join(out["notes"]), ""]
    peers = []
    for _key, r in out["datasets"].items():
        for stage in ("segmentation", "surface"):
            name = _get(r, stage, "peer", "name")
            if name:
                name = re.sub(r" on the \([0-9, ]+\) mask", " on the same mask (level 0.5)", name)
            if name and name not in peers:
                peers.append(name)
    if peers:
        L += ["**Peers** (run in the same process and run as ours): " + "; ".join(f"`{p}`" for p in peers)
              + "; storage: a binary STL of the marching-cubes mesh, written with numpy. Each mesh stage also"
              " builds its result as a Blender mesh with the add-on's `build_mesh_object`.", ""]
    return L


def _md_targets(out: dict) -> list[str]:
    L = ["## Targets", "", "| target | goal | measured | status |", "|---|---|---|---|"]
    for t in out.get("targets", []):
        L.append(f"| {t['name']} | {t['target']} | {t['measured']}{(' (' + t['note'] + ')') if t['note'] else ''}"
                 f" | {_met(t['met'])} |")
    L.append("")
    return L


def _md_speed(ds: dict) -> list[str]:
    L = ["## Speed: ours against the peer (same run, same input)", "",
         "| data | stage | ours | peer | peer / ours | target |", "|---|---|---|---|---|---|"]
    for key, r in ds.items():
        lab = key
        if "error" in r and "load" not in r:
            L.append(f"| {lab} | - | {r['error']} | | | |")
            continue
        for rows in (_speed_load, _speed_segmentation, _speed_boundaries, _speed_surface, _speed_wfield):
            L += rows(key, r)
    L.append("")
    return L


def _error_row(lab: str, stage: str, record: dict) -> list[str]:
    """The speed table's row of a stage that failed ([] when its record has no error either)."""
    return [f"| {lab} | {stage} | {record['error']} | | | |"] if "error" in record else []


def _speed_load(lab: str, r: dict) -> list[str]:
    ld = r.get("load", {})
    if "time" in ld:
        return [f"| {lab} | load {('x'.join(map(str, ld['shape'])))} | {_ms(ld['time']['median_s'])} | - | - | - |"]
    return _error_row(lab, "load", ld)


def _speed_segmentation(key: str, r: dict) -> list[str]:
    sg = r.get("segmentation", {})
    if "ours" not in sg:
        return _error_row(key, "segmentation", sg)
    peer = sg.get("peer")
    jo = sg["ours"].get("slice_jaccard_mean")
    ours_txt = f"{_ms(sg['ours']['time']['median_s'])}" + (f", slice J {jo:.4f}" if jo is not None else "")
    if peer:
        ptxt = (f"{_ms(peer['per_slice_s'])}/slice x {sg['head_slices']} = "
                f"{_ms(peer['all_head_slices_s'])}, slice J {peer['slice_jaccard_mean_raw']:.4f} raw / "
                + (f"{peer['slice_jaccard_mean_cleaned']:.4f}" if peer.get("cleaned_valid", True) else
                   "n/a (3-D clean-up needs every slice)") + " with our clean-up"
                f" (ours {peer['ours_slice_jaccard_mean_same_slices']:.4f} there)"
                + (f" [{peer['slices']}-slice subset, extrapolated]" if peer["subset"] else
                   f" [all {peer['slices']} head slices, measured]"))
        return [f"| {key} | segmentation | {ours_txt} | {ptxt} | {sg['ratio']:.1f}x | "
                + ("<= 2 s, >= 5x" if key == "cthead" else "-") + " |"]
    extra = (f"; mask = {100 * sg['ours']['mask_fraction']:.1f}% of the volume"
             if "mask_fraction" in sg["ours"] else "")
    return [f"| {key} | segmentation | {ours_txt}{extra} | {sg.get('note', '-')} | - | - |"]


def _speed_boundaries(lab: str, r: dict) -> list[str]:
    bd = r.get("boundaries", {})
    if "time" in bd:
        return [f"| {lab} | boundaries t={bd['patches']}, "
                f"M=256{', ' + bd['parameterisation'] if bd.get('parameterisation') else ''} | "
                f"{_ms(bd['time']['median_s'])} | - | - | "
                f"(paper: {PAPER['boundary_seconds']} s) |"]
    return _error_row(lab, "boundaries", bd)


def _speed_surface(key: str, r: dict) -> list[str]:
    su = r.get("surface", {})
    if "ours" not in su:
        return _error_row(key, "solve+surface", su)
    o, p = su["ours"], su["peer"]
    L = [f"| {key} | solve + surface(40,60), engine | {_ms(o['engine']['median_s'])} (solve alone "
         f"{_ms(o['solve_only']['median_s'])}) | marching cubes {_ms(p['engine']['median_s'])} "
         f"({p['faces']:,} triangles) | {su['ratio_engine']:.0f}x | - |"]
    if "blender" in o:
        L.append(f"| {key} | Blender mesh build | {_ms(o['blender']['median_s'])} ({o['faces']} faces, capped) | "
                 f"{_ms(p['blender']['median_s'])} | {p['blender']['median_s'] / o['blender']['median_s']:.0f}x | - |")
        L.append(f"| {key} | **engine (capped) + Blender** | {_ms(o['total_median_s'])} | "
                 f"{_ms(p['total_median_s'])} | **{su['ratio_total']:.0f}x** | "
                 + (">= 100x" if key == "cthead" else "-") + " |")
    return L


def _speed_wfield(key: str, r: dict) -> list[str]:
    wf = r.get("wfield", {})
    if "ours" not in wf:
        return _error_row(key, "w_field", wf)
    L = [f"| {key} | w_field {'x'.join(map(str, wf['ours']['grid']))} | {_ms(wf['ours']['time']['median_s'])}"
         f" | - | - | " + ("<= 1 s" if key == "cthead" else "-") + " |"]
    if "vdb" in wf:
        L.append(f"| {key} | write_vdb | {_ms(wf['vdb']['time']['median_s'])} ({wf['vdb']['bytes'] / 1024:.0f} kB)"
                 f" | - | - | - |")
    return L


def _md_storage(ds: dict) -> list[str]:
    L = ["## Storage", "", "| data | ours: boundary file | peer: binary STL of marching cubes | peer / ours |",
         "|---|---|---|---|"]
    for key, r in ds.items():
        s = r.get("storage")
        if s and "ours" in s:
            peer = s.get("peer")
            L.append(f"| {key} | {s['ours']['bytes'] / 1024:.1f} kB ({s['ours']['name'].split('(')[-1].rstrip(')')}) | "
                     + (f"{peer['bytes'] / 1024:,.0f} kB ({peer['triangles']:,} triangles) | {s['ratio']:.0f}x |"
                        if peer else "- | - |"))
        elif s:
            L.append(f"| {key} | {s.get('error')} | | |")
    L += [f"| paper (CThead, 99 slices) | {PAPER['storage_ours_kB']} kB | {PAPER['storage_mc_kB']:,} kB | "
          f"{PAPER['storage_mc_kB'] / PAPER['storage_ours_kB']:.0f}x |", ""]
    return L


def _fidelity_cells(row: dict, prefix: str) -> str:
    if prefix + "mean" in row:
        return f"{row[prefix + 'mean']:.2f} | {row[prefix + 'p95']:.2f} | {row[prefix + 'max']:.2f}"
    return f"{row.get(prefix + 'error', '-')} | | "


def _md_fidelity(ds: dict) -> list[str]:
    L = ["## Fidelity: PDE surface against marching cubes (paper Fig. 12 in numbers)", "",
         "Symmetric surface distance (`pdehead_addon.validation.surface_metrics.symmetric_surface_distance`, mm), both"
         f" directions pooled: {FIDELITY_DEFINITION}. t=10 and t=31 are the targets' rows.", "",
         f"Slices chosen by `{SELECTION}` (the add-on's default; the targets' numbers); the last columns"
         " use the paper's evenly spaced (`uniform`) slices for comparison. The max is dominated by the"
         " marching-cubes surface of cavities inside the mask (e.g. the mouth), which the PDE skin has not.",
         "", "| data | t | slices used | mean | p95 | max | uniform: mean | p95 | max |",
         "|---|---|---|---|---|---|---|---|---|"]
    for key, r in ds.items():
        f = r.get("fidelity")
        if not f:
            continue
        if "series" not in f:
            L.append(f"| {key} | - | {f.get('error')} | | | | | | |")
            continue
        for row in f["series"]:
            L.append(f"| {key} | {row['t']} | {row['slices_used']} | {_fidelity_cells(row, '')} | "
                     f"{_fidelity_cells(row, 'uniform_')} |")
    L.append("")
    return L


def _md_uv(ds: dict) -> list[str]:
    uv = _get(ds, "cthead", "uv")
    if not (uv and "rows" in uv):
        return []
    L = ["## uv resolution (paper Fig. 13), CThead t=10", "",
         f"Median of {uv['repeats']} runs. Engine = `PDEHead.surface(nu, nv)` (open tube, bench_pde."
         "bench_surface; the 200 x 400 row is the target's); with caps = `surface(nu, nv, caps=True)`, what"
         " the add-on builds; Blender = `build_mesh_object` of the capped mesh; total = with caps + Blender.",
         "", "| nu x nv | vertices | engine | engine, with caps | Blender build | total |",
         "|---|---|---|---|---|---|"]
    for row in uv["rows"]:
        L.append(f"| {row['nu']} x {row['nv']} | {row['vertices']} | {_ms(row['engine']['median_s'])} | "
                 f"{_ms(row['engine_with_caps']['median_s'])} | {_ms(_get(row, 'blender', 'median_s'))} | "
                 f"{_ms(row.get('total_median_s'))} |")
    L.append("")
    return L


#: The memory table's rows: (stage, path of its RSS record in a data set's results, tracemalloc key).
_MEMORY_ROWS = (("load", ("load", "memory_rss"), None),
                ("segmentation", ("segmentation", "ours", "memory_rss"), "segmentation_MB"),
                ("boundaries (+ align)", ("boundaries", "memory_rss"), "boundaries_MB"),
                ("solve + surface(40,60)", ("surface", "ours", "memory_rss"), "solve_surface_MB"),
                ("w_field", ("wfield", "ours", "memory_rss"), "w_field_MB"),
                ("marching cubes (peer)", ("surface", "peer", "memory_rss"), "marching_cubes_MB"))


def _md_memory(out: dict) -> list[str]:
    L = ["## Memory", "",
         "RSS = resident set size high-water mark of the process during OUR call only (VmHWM reset through"
         " /proc/self/clear_refs before it), as the increase over the RSS at its start, all repeats included;"
         " it can be lower than what the call allocates when the allocator reuses memory still resident from"
         " an earlier stage. tracemalloc = peak of the Python/numpy allocations of the call in a separate"
         " untimed pass (CThead, full runs).", "",
         "| data | stage | RSS increase | tracemalloc peak |", "|---|---|---|---|"]
    for key, r in out["datasets"].items():
        tm = r.get("memory_tracemalloc", {})
        for name, path, tkey in _MEMORY_ROWS:
            mr = _get(r, *path)
            tmv = tm.get(tkey) if tkey else None
            if mr is None and tmv is None:
                continue
            L.append(f"| {key} | {name} | " + (f"{mr['rss_increase_MB']:.0f} MB" if mr else "-") + " | "
                     + (f"{tmv:.0f} MB" if isinstance(tmv, (int, float)) else "-") + " |")
    mem = out.get("memory_512")
    if mem:
        L.append("")
        if "stages" in mem:
            L.append(f"512 x 512 x 300 (phantom written as DICOM, fresh "
                     f"process): peak RSS **{mem['peak_rss_MB']:.0f} MB**"
                     f" over load -> segmentation -> boundaries -> solve+surface(200,400) -> w_field (baseline "
                     f"{mem['baseline_rss_MB']:.0f} MB). Per stage (high-water MB, seconds): "
                     + ", ".join(f"{k} {v.get('rss_hwm_MB', float('nan')):.0f} MB / "
                                 f"{v.get('seconds', float('nan')):.1f} s"
                                 if "error" not in v else f"{k}: {v['error']}" for k, v in mem["stages"].items()) + ".")
        else:
            L.append(f"512 x 512 x 300: {mem.get('error')}")
    L.append("")
    return L


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def write_outputs(out: dict, json_path: Path, md_path: Path) -> None:
    """The measured JSON (with the run's metadata, write_docs.save) and the markdown rendered from it alone (the
    sections other benchmark scripts own stay)."""
    import write_docs  # scripts/bench/: the JSON's metadata and the docs (it imports this module to render)
    md_path.parent.mkdir(parents=True, exist_ok=True)
    out = write_docs.save(json_path, json.loads(json.dumps(out, default=_json_default)), out.get("repeats"))
    write_docs.write("main", out, md_path)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="< 1 min: phantom + CThead, fewer repeats, peers on a subset")
    p.add_argument("--repeats", type=int, default=None, help="runs per measurement (median); default 5 (quick: 2)")
    p.add_argument("--datasets", help="comma list of phantom,cthead,cthead_tiff8,ge,mri (default: all; quick: "
                                      "phantom,cthead)")
    p.add_argument("--stages", help="comma list of " + ",".join(STAGES))
    p.add_argument("--no-blender", action="store_true", help="skip the Blender mesh builds and the VDB write")
    p.add_argument("--out", type=Path, default=None, help="JSON output (default docs/benchmarks.json)")
    p.add_argument("--md", type=Path, default=None, help="markdown output (default docs/benchmarks.md)")
    p.add_argument("--render-only", action="store_true",
                   help="only rewrite the markdown from the JSON (--out) without measuring")
    p.add_argument("--memory-probe", help=argparse.SUPPRESS)
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.memory_probe:
        memory_probe(args.memory_probe)
        return 0
    json_path = args.out or DOCS / "benchmarks.json"
    md_path = args.md or DOCS / "benchmarks.md"
    if args.render_only:  # rewrite the markdown (and targets) from an existing JSON, no measuring
        import write_docs
        out = json.loads(json_path.read_text())
        out["targets"] = targets(out)       # the targets' verdicts from the measured numbers (the run's metadata kept)
        json_path.write_text(json.dumps(out, indent=1, default=_json_default) + "\n")
        write_docs.write("main", out, md_path)
        print(f"rewrote {md_path} from {json_path}")
        return 0
    out = Bench(args).run()
    write_outputs(out, json_path, md_path)
    print(f"wrote {json_path} and {md_path} in {out['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
