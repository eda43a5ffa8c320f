#!/usr/bin/env python3
"""Accuracy of the automatic craniometric landmarks (issue 22), per landmark.

* the phantom (``make_phantom``, default 20 HU noise) on its default grid (2.3 x 2 x 2 mm) and on a
  1.44 x 1 x 1 mm grid, against the analytic positions of its facial skeleton
  (:meth:`Phantom.bone_landmarks`);
* CThead (``/work/shared/data/cthead_stanford/raw16``) against the positions placed by hand from its
  slices (``tests/fixtures/cthead_landmarks.csv``, which says how each was placed).

The bone mask is ``segment_skull(ct).bone`` (the default bone level); the landmarks come from
``find_landmarks(ct, bone)``. Error = Euclidean distance (mm) between the automatic and the
reference point. Targets (CThead): median <= 3 mm, every ``ok`` landmark <= 6 mm.

Usage::

    python3 scripts/bench/bench_landmarks.py                   # prints the table, writes docs/benchmarks.md section
    python3 scripts/bench/bench_landmarks.py --no-write --summary-json out.json
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import write_docs  # noqa: E402  (the JSON's run metadata and the docs section)
from _common import CTHEAD_RAW16_OPTIONS, SHARED_DATA  # noqa: E402

FIXTURE = ROOT / "tests" / "fixtures" / "cthead_landmarks.csv"


def read_fixture(path: Path = FIXTURE) -> dict[str, tuple[np.ndarray, str]]:
    """Hand-placed landmarks: name -> (patient mm, how it was placed)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    return {r["landmark"]: (np.array([float(r[k]) for k in ("x_mm", "y_mm", "z_mm")]), r["how"]) for r in rows}


def errors(search, reference: dict[str, np.ndarray]) -> dict[str, tuple[str, float]]:
    """name -> (flag, error mm; NaN when not found) for the reference landmarks."""
    out = {}
    for name, ref in reference.items():
        lm = search.landmarks[name]
        err = float("nan") if lm.point is None else float(np.linalg.norm(lm.point - ref))
        out[name] = (lm.flag, err)
    return out


def summary(errs: dict[str, tuple[str, float]]) -> dict:
    found = [e for f, e in errs.values() if np.isfinite(e)]
    ok = [e for f, e in errs.values() if f == "ok" and np.isfinite(e)]
    return {"landmarks": len(errs), "found": len(found), "ok": len(ok),
            "median_mm": float(np.median(found)) if found else None,
            "max_ok_mm": float(max(ok)) if ok else None, "max_mm": float(max(found)) if found else None}


def run_phantom(shape=None) -> tuple[dict, float]:
    from pdehead_addon import make_phantom
    from pdehead_addon.forensic.auto_landmarks import find_landmarks
    from pdehead_addon.forensic.skull import segment_skull

    ph = make_phantom() if shape is None else make_phantom(shape=shape)
    bone = segment_skull(ph.ct).bone
    t0 = time.perf_counter()
    search = find_landmarks(ph.ct, bone)
    seconds = time.perf_counter() - t0
    return errors(search, ph.bone_landmarks()), seconds


def run_cthead() -> tuple[dict, float, dict]:
    from pdehead_addon import load_ct
    from pdehead_addon.forensic.auto_landmarks import find_landmarks
    from pdehead_addon.forensic.skull import segment_skull

    ct = load_ct(SHARED_DATA / "cthead_stanford" / "raw16", **CTHEAD_RAW16_OPTIONS)
    bone = segment_skull(ct).bone
    t0 = time.perf_counter()
    search = find_landmarks(ct, bone)
    seconds = time.perf_counter() - t0
    ref = read_fixture()
    flags = {n: (lm.flag, lm.evidence) for n, lm in search.landmarks.items()}
    return errors(search, {n: p for n, (p, _) in ref.items()}), seconds, flags


def _fmt(e: float) -> str:
    return "not found" if not np.isfinite(e) else f"{e:.1f}"


def markdown(results: dict, cthead_flags: dict) -> str:
    lines = ["## Automatic craniometric landmarks (issue 22): `python3 scripts/bench/bench_landmarks.py`", "",
             "Distance (mm) from each automatic landmark (`find_landmarks` on `segment_skull(ct).bone`) to its "
             "reference, and the landmark's flag. References: the phantom's analytic facial skeleton "
             "(`Phantom.bone_landmarks`: the written rule evaluated on the exact geometry); on CThead, positions "
             "placed by hand on its slices (`tests/fixtures/cthead_landmarks.csv` says how, landmark by landmark). "
             "Targets on CThead: median <= 3 mm, every `ok` landmark <= 6 mm. One run each (the errors are "
             "deterministic); the time is `find_landmarks` alone, on this 2-core machine shared with other jobs.", ""]
    for key, title in (("phantom", "Phantom, default grid (2.3 x 2 x 2 mm, 20 HU noise)"),
                       ("phantom_fine", "Phantom, 1.44 x 1 x 1 mm grid (160 x 256 x 256)"),
                       ("cthead", "CThead (2 x 1 x 1 mm), against the hand-placed fixture")):
        r = results[key]
        s = r["summary"]
        lines += [f"### {title}", "",
                  f"{s['found']} of {s['landmarks']} reference landmarks found ({s['ok']} `ok`); median error "
                  f"**{s['median_mm']:.1f} mm**, largest `ok` error **{s['max_ok_mm']:.1f} mm**, largest "
                  f"{s['max_mm']:.1f} mm; `find_landmarks` {r['seconds']:.1f} s.", "",
                  "| landmark | flag | error mm |", "|---|---|---:|"]
        for name, (flag, err) in r["errors"].items():
            lines.append(f"| {name} | {flag} | {_fmt(err)} |")
        lines.append("")
    c = results["cthead"]["summary"]
    lines += ["### Against the targets", "",
              f"CThead: median {c['median_mm']:.1f} mm (target <= 3 mm: "
              f"{'met' if c['median_mm'] <= 3 else 'NOT met'}); largest `ok` error {c['max_ok_mm']:.1f} mm "
              f"(target <= 6 mm: {'met' if c['max_ok_mm'] <= 6 else 'NOT met'}).", "",
              "Where the error comes from (CThead), measured landmark by landmark: the mid-sagittal plane is the "
              "symmetry plane of the bone's surface voxels (20,000, picked by a fixed random field); the whole "
              "bone's 4,000 voxels used before put the chin 1.9 mm and the vault's top 5 mm off the bone's own "
              "midline. The symphysis' front-most bone spans x = 99..123 (centre 110.8) where the fixture "
              "places every facial landmark on the single sagittal slice x = 108: about 3 mm of the chin "
              "landmarks' error is that x. The vault's top is flat and sits 3-4 mm to the right of the skull's "
              "plane, so vertex is the middle of the top within 30 mm of the plane (its y along the flat top is "
              "the rest of its error). Porion: the temporal bone above the meatus reaches 4-6 mm beyond the "
              "canal's floor; porion is put half way back along the roof, and flagged "
              "`uncertain` beyond 3 mm (the fixture puts it at the canal's "
              "lateral end). Glabella: this forehead has no "
              "prominence, the fixture places it 12 mm above nasion. Supradentale, infradentale: teeth and "
              "alveolar bone are one object in a bone mask (`uncertain`). Zygion and gonion lie on flat or "
              "rounded bone, where a person and a rule pick points several mm apart. The references themselves "
              "are good to about 1-2 mm. On the phantom the margins of the orbits (supraorbital, lateral orbit) "
              "are the front-most bone of the first 3 mm next to the opening: the first bone pixel of a steep rim "
              "lies up to 10 mm behind its edge.", "",
              "Flags on CThead of the landmarks without a hand-placed reference (the evidence for `uncertain` "
              "and `not_found`):", "", "| landmark | flag | evidence |", "|---|---|---|"]
    ref = results["cthead"]["errors"]
    for name, (flag, ev) in cthead_flags.items():
        if name not in ref:
            lines.append(f"| {name} | {flag} | {ev} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--no-write", action="store_true", help="do not update docs/benchmarks.md")
    p.add_argument("--summary-json", type=Path, help="write the results as JSON (default with the docs: "
                                                     "docs/benchmarks_landmarks.json)")
    p.add_argument("--md", type=Path, default=write_docs.DOCS / "benchmarks.md", help="the markdown file to write")
    write_docs.add_arguments(p, "landmarks")
    args = p.parse_args(argv)
    if args.from_json:
        write_docs.write("landmarks", write_docs.load(args.from_json), args.md)
        return 0
    results = {}
    for key, shape in (("phantom", None), ("phantom_fine", (160, 256, 256))):
        print(f"bench_landmarks: phantom {shape or 'default'} ...", file=sys.stderr)
        errs, sec = run_phantom(shape)
        results[key] = {"errors": errs, "seconds": sec, "summary": summary(errs)}
    print("bench_landmarks: CThead ...", file=sys.stderr)
    errs, sec, flags = run_cthead()
    results["cthead"] = {"errors": errs, "seconds": sec, "summary": summary(errs)}
    saved = {k: {"summary": v["summary"], "seconds": v["seconds"],
                 "errors": {n: {"flag": f, "error_mm": None if not np.isfinite(e) else float(e)}
                            for n, (f, e) in v["errors"].items()}} for k, v in results.items()}
    saved["cthead_flags"] = {name: list(flag_evidence) for name, flag_evidence in flags.items()}
    if args.summary_json or not args.no_write:
        saved = write_docs.save(args.summary_json or write_docs.SECTIONS["landmarks"].json_path, saved, 1)
    text = write_docs.write("landmarks", saved, args.md) if not args.no_write else render(saved)
    print(text)
    return 0


def render(saved: dict) -> str:
    """The section from the JSON :func:`main` writes (a landmark not found: ``error_mm`` null)."""
    results = {key: {"summary": saved[key]["summary"], "seconds": saved[key]["seconds"],
                     "errors": {n: (e["flag"], float("nan") if e["error_mm"] is None else e["error_mm"])
                                for n, e in saved[key]["errors"].items()}}
               for key in ("phantom", "phantom_fine", "cthead")}
    return markdown(results, {name: tuple(fe) for name, fe in saved["cthead_flags"].items()})


if __name__ == "__main__":
    sys.exit(main())
