"""One study of a batch run (``scripts/pdehead_batch.py``): the engine only, no bpy, no Dask.

:func:`run_study` is what a batch worker calls for one input. It runs the study in a child process
(``python batch_study.py --child``) so that a per-study time and memory limit can end a runaway study
without taking the worker down, writes the study's files into a private work folder, and moves that
folder into place only when the study succeeded: ``DIR/<study_id>/`` then holds either the complete
result or, for a failed study, only ``log.txt``, ``settings.json`` and ``result.json`` (the error).

What a study writes (section 5.2's compact storage and the forensic ground work):

- ``boundaries.pdeh``: the boundary file (:func:`pdehead_addon.save_boundaries`);
- with ``skull``: ``skull.stl`` (the bone surface) and ``landmarks.csv`` (the automatic landmarks with
  their tissue depths and flags);
- ``log.txt``: per-step times and warnings (with ``skull``: each depth's ray, and why a depth is
  uncertain); ``settings.json``: the software version, the settings, the input fingerprint and the
  series that was used (plus the sex and age a depth table may split by; never a patient's name or ID);
  ``result.json``: the record that ``summary.csv`` gets.

A re-run skips a study whose input fingerprint (every file's size and modification time) and settings
are unchanged (:func:`is_current`).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

#: Bumped when what a study writes changes, so that a re-run redoes studies made by an older runner.
RUNNER_VERSION = 3
#: Default per-study limits: wall time (s) and resident memory of the study's process (MB). A study of a
#: 512 x 512 x 300 head CT takes about 40 s and 3 GB; these leave room for larger scans on a slow machine.
DEFAULT_TIME_LIMIT_S = 900.0
DEFAULT_MEMORY_LIMIT_MB = 8000.0
#: Names of the files a finished study folder holds (``skull.stl`` and ``landmarks.csv`` with ``skull``).
RESULT_FILE = "result.json"
SETTINGS_FILE = "settings.json"
LOG_FILE = "log.txt"
BOUNDARY_FILE = "boundaries.pdeh"
_NII_SUFFIXES = (".nii.gz", ".nii", ".tar.gz")


# --------------------------------------------------------------------------- identity and fingerprint
def study_id(input_path: str | os.PathLike) -> str:
    """The study's folder name: the input's folder or file name made safe, and 8 hex digits of a hash of
    its absolute path (two inputs with one name stay apart; a patient name in DICOM tags is never used)."""
    path = Path(input_path).expanduser().absolute()
    name = path.name
    for suffix in _NII_SUFFIXES:
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._-")[:48] or "study"
    digest = hashlib.sha256(os.fsencode(str(path))).hexdigest()[:8]
    return f"{safe}_{digest}"


def input_fingerprint(input_path: str | os.PathLike) -> dict:
    """Every file of the input with its size and modification time (ns), and a hash of that list.

    A folder is walked recursively in sorted order; hidden files are left out. A missing input has the
    fingerprint ``{"missing": True}`` (the study then fails with that error).
    """
    path = Path(input_path).expanduser().absolute()
    if not path.exists():
        return {"files": 0, "bytes": 0, "hash": "", "missing": True}
    if path.is_file():
        files = [path]
    else:
        files = sorted(p for p in path.rglob("*") if p.is_file()
                       and not any(part.startswith(".") for part in p.relative_to(path).parts))
    rows = []
    for f in files:
        st = f.stat()
        rows.append([str(f.relative_to(path)) if f != path else f.name, st.st_size, st.st_mtime_ns])
    digest = hashlib.sha256(json.dumps(rows).encode()).hexdigest()
    return {"files": len(rows), "bytes": int(sum(r[1] for r in rows)), "hash": digest}


def _settings_key(settings: dict) -> str:
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()


def is_current(study_dir: Path, fingerprint: dict, settings: dict) -> dict | None:
    """The stored record when ``study_dir`` was made by this runner from the same input and settings."""
    try:
        record = json.loads((study_dir / RESULT_FILE).read_text())
    except (OSError, ValueError):
        return None
    if (record.get("runner_version") == RUNNER_VERSION and record.get("input_hash") == fingerprint.get("hash")
            and record.get("settings_key") == _settings_key(settings) and not fingerprint.get("missing")):
        return record
    return None


# --------------------------------------------------------------------------- the parent side
def run_study(input_path: str, out_dir: str, settings: dict, time_limit_s: float = DEFAULT_TIME_LIMIT_S,
              memory_limit_mb: float = DEFAULT_MEMORY_LIMIT_MB, force: bool = False) -> dict:
    """Run one study in a child process within the limits; returns its ``summary.csv`` record.

    The record has ``study_id, input, status ('ok' or 'failed'), error, seconds, n_landmarks, warnings``
    and ``skipped`` (True when the study was current and nothing ran). Never raises for a bad study.
    """
    out = Path(out_dir)
    sid = study_id(input_path)
    study_dir = out / sid
    fingerprint = input_fingerprint(input_path)
    if not force:
        record = is_current(study_dir, fingerprint, settings)
        if record is not None:
            return {**record, "skipped": True}
    work = Path(tempfile.mkdtemp(prefix=f".work-{sid}-", dir=out))
    t0 = time.perf_counter()
    error, peak_mb = "", 0.0
    try:
        if fingerprint.get("missing"):
            error = f"{input_path}: no such file or folder"
        else:
            error, peak_mb = _run_child(input_path, work, settings, time_limit_s, memory_limit_mb)
    except Exception as exc:  # the runner itself failed: record it, never stop the batch
        error = f"internal error: {type(exc).__name__}: {exc}"
    except BaseException:  # Ctrl-C or a cancelled task: the study is not recorded, nothing is left
        shutil.rmtree(work, ignore_errors=True)
        raise
    seconds = time.perf_counter() - t0
    child = {}
    try:
        child = json.loads((work / "child.json").read_text())
    except (OSError, ValueError):
        pass
    if not error and child.get("error"):
        error = child["error"]
    record = {
        "study_id": sid, "input": str(input_path), "status": "failed" if error else "ok", "error": error,
        "seconds": round(seconds, 2), "n_landmarks": int(child.get("n_landmarks", 0)) if not error else 0,
        "warnings": list(child.get("warnings", [])), "peak_mb": round(peak_mb, 1), "runner_version": RUNNER_VERSION,
        "input_hash": fingerprint.get("hash", ""), "settings_key": _settings_key(settings),
    }
    meta = {"software": _software(), "settings": settings, "input": str(input_path),
            "fingerprint": fingerprint, "series": child.get("series", {}), "subject": child.get("subject", {}),
            "patches_used": child.get("patches"), "limits": {"time_s": time_limit_s, "memory_mb": memory_limit_mb}}
    if error:  # nothing half-written: a failed study keeps only its log, settings and error
        for f in work.iterdir():
            if f.name not in (LOG_FILE,):
                _remove(f)
        if not (work / LOG_FILE).exists():
            (work / LOG_FILE).write_text(f"failed: {error}\n")
    else:
        (work / "child.json").unlink(missing_ok=True)
    (work / SETTINGS_FILE).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    (work / RESULT_FILE).write_text(json.dumps(record, indent=2) + "\n")
    _replace_dir(work, study_dir)
    return {**record, "skipped": False}


def _software() -> dict:
    import numpy

    import pdehead_addon
    return {"pdehead": pdehead_addon.__version__, "python": sys.version.split()[0], "numpy": numpy.__version__,
            "runner_version": RUNNER_VERSION}


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _replace_dir(new: Path, target: Path) -> None:
    """Put the finished work folder in place of ``target`` (the old result goes only once the new one is whole)."""
    old = None
    if target.exists():
        old = target.with_name(f".old-{target.name}-{os.getpid()}-{time.monotonic_ns()}")
        target.rename(old)
    new.rename(target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _die_with_parent() -> None:
    """Linux: the study's process gets SIGKILL when the worker that started it dies (a cluster shut down
    or a worker killed must not leave studies running on); elsewhere nothing."""
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
        except OSError:
            pass


def remove_stale_work(out: Path, older_than_s: float) -> int:
    """Remove work folders left by a run that was killed (older than ``older_than_s``); returns the count."""
    now = time.time()
    stale = [p for p in out.glob(".work-*") if p.is_dir() and now - p.stat().st_mtime > older_than_s]
    stale += [p for p in out.glob(".old-*") if p.is_dir()]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def _run_child(input_path: str, work: Path, settings: dict, time_limit_s: float,
               memory_limit_mb: float) -> tuple[str, float]:
    """Run the study's child process: ('' on success, else the one-line reason it ended; its peak RSS in MB)."""
    import psutil

    cmd = [sys.executable, os.path.abspath(__file__), "--child", str(input_path), str(work), json.dumps(settings)]
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    with open(work / LOG_FILE, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                                preexec_fn=_die_with_parent)
        handle = psutil.Process(proc.pid)
        t0 = time.monotonic()
        peak = 0.0
        try:
            while proc.poll() is None:
                try:
                    peak = max(peak, handle.memory_info().rss / 1e6)
                except psutil.Error:
                    pass
                if peak > memory_limit_mb:
                    proc.kill()
                    proc.wait()
                    return f"ended: memory above the per-study limit of {memory_limit_mb:.0f} MB (--memory-limit)", peak
                if time.monotonic() - t0 > time_limit_s:
                    proc.kill()
                    proc.wait()
                    return f"ended: took longer than the per-study limit of {time_limit_s:g} s (--time-limit)", peak
                time.sleep(0.05)
        except BaseException:  # Ctrl-C or a cancelled task: never leave a child behind
            proc.kill()
            proc.wait()
            raise
    if proc.returncode != 0 and not (work / "child.json").exists():
        tail = (work / LOG_FILE).read_text(errors="replace").strip().splitlines()[-1:] or [""]
        return f"the study's process exited with status {proc.returncode}: {tail[0][:200]}", peak
    return "", peak


# --------------------------------------------------------------------------- the child side
def _series_and_subject(ct, input_path: str) -> tuple[dict, dict]:
    """The series used, and the subject's sex and age fields (DICOM only; never name or ID)."""
    meta = ct.meta
    series = {k: meta.get(k) for k in ("format", "series_uid", "series_description", "original_slice_count",
                                       "modality") if meta.get(k) is not None}
    series["shape"] = list(ct.shape)
    series["spacing_mm"] = [round(float(s), 6) for s in ct.spacing]
    subject: dict = {}
    if meta.get("format") == "dicom":
        subject = _dicom_subject(Path(input_path), meta.get("series_uid"))
    return series, subject


def _dicom_subject(path: Path, series_uid: str | None) -> dict:
    import pydicom

    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        try:
            ds = pydicom.dcmread(f, stop_before_pixels=True,
                                 specific_tags=["SeriesInstanceUID", "PatientSex", "PatientAge",
                                                "PatientBirthDate", "StudyDate"])
        except Exception:
            continue
        if series_uid and str(ds.get("SeriesInstanceUID", "")) != series_uid:
            continue
        return {"sex": str(ds.get("PatientSex", "") or ""), "age": str(ds.get("PatientAge", "") or ""),
                "birth_date": str(ds.get("PatientBirthDate", "") or ""),
                "study_date": str(ds.get("StudyDate", "") or "")}
    return {}


def _child(input_path: str, work: Path, settings: dict) -> int:
    import numpy as np  # noqa: F401  (imported before the engine so its import time is not a step's)

    import pdehead_addon as eng

    state = {"warnings": [], "n_landmarks": 0}
    caught: list[str] = []

    def step(name, fn):
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as ws:
            warnings.simplefilter("always")
            value = fn()
        for w in ws:
            caught.append(f"{name}: {str(w.message).splitlines()[0]}")
        print(f"{name}: {time.perf_counter() - t0:.2f} s", flush=True)
        return value

    try:
        ct = step("import", lambda: eng.load_ct(input_path, **_loader_options(settings)))
        eng.check_head_scan(ct)                 # portraits, noise: refused before the segmentation
        state["series"], state["subject"] = _series_and_subject(ct, input_path)
        seg = step("segment", lambda: eng.segment_head(ct))
        # a short scan gives the patches it can, as in the add-on, said among the study's warnings
        patches, message = eng.patches_for_scan(seg, settings["patches"])
        if message:
            caught.append(f"boundaries: {message}")
        state["patches"] = patches
        bset = step("boundaries", lambda: eng.extract_boundaries(
            seg, patches=patches, samples=settings["samples"], selection=settings["selection"]))
        step("save", lambda: eng.save_boundaries(bset, work / BOUNDARY_FILE))
        if settings.get("skull"):
            state["n_landmarks"] = step("skull", lambda: _skull_outputs(eng, ct, seg, bset, work, settings))
    except eng.PDEHeadError as exc:
        state["error"] = str(exc).splitlines()[0]
    except MemoryError:
        state["error"] = "out of memory"
    except Exception as exc:
        traceback.print_exc()
        state["error"] = f"internal error: {type(exc).__name__}: {exc}"
    state["warnings"] = list(dict.fromkeys(caught))
    for w in state["warnings"]:
        print(f"warning: {w}", flush=True)
    if state.get("error"):
        print(f"failed: {state['error']}", flush=True)
    (work / "child.json").write_text(json.dumps(state))
    return 0


def _loader_options(settings: dict) -> dict:
    """``load_ct`` keyword arguments of the batch's loader options (``_common.engine_loader_options``)."""
    options = dict(settings.get("loader") or {})
    for key in ("shape", "spacing"):                 # lists after the JSON round trip
        if key in options:
            options[key] = tuple(options[key])
    return options


def _skull_outputs(eng, ct, seg, bset, work: Path, settings: dict) -> int:
    """skull.stl (the bone), and landmarks.csv: every automatic landmark with its flag, its depth along the
    bone's exposed normal from the bone level's crossing to the skin level's in the CT's interpolated
    intensities (:func:`~pdehead_addon.forensic.depth_on_ct.landmark_depths_on_ct`), and the default table's mean and
    SD;
    returns the number found. A depth the intensity profile does not support turns an ``ok`` landmark
    ``uncertain``; the measured reason goes to log.txt."""
    from pdehead_addon.core.provenance import provenance
    from pdehead_addon.forensic.auto_landmarks import find_landmarks
    from pdehead_addon.forensic.depth_on_ct import depth_flags, depth_levels, measure_landmark_depths
    from pdehead_addon.forensic.depth_table import default_table, write_landmark_csv
    from pdehead_addon.forensic.skull import segment_skull, skull_mesh

    skull = segment_skull(ct, seg)
    bone = skull_mesh(skull)
    eng.export_mesh(bone, work / "skull.stl")
    # a skull alone (no soft tissue in the CT): the head's outline is the bone, no skin and no depths
    skin = eng.solve_pde(bset).surface(int(settings.get("nu", 120)), int(settings.get("nv", 240)), caps=True) \
        if skull.meta.get("has_skin", True) else None
    if skin is None:
        print("no skin: the CT shows no soft tissue (a skull alone): landmarks without depths", flush=True)
    search = find_landmarks(ct, skull.bone, mandible=skull.mandible)
    found = search.points()  # ok and uncertain
    levels = depth_levels(skull)
    table = default_table()
    measured = measure_landmark_depths(found, bone, skin, skull, head_mask=seg.mask, table=table)
    flags = depth_flags(search.flags(), measured)
    for name, m in measured.items():  # the ray of every depth, for an audit (and the tests' truth)
        print(f"depth ray: {name}: direction {m.direction[0]:.5f} {m.direction[1]:.5f} {m.direction[2]:.5f}, "
              f"mesh depth {m.mesh_depth:.2f} mm", flush=True)
        if not m.trusted:
            print(f"depth uncertain: {name}: {m.evidence}", flush=True)
    missing = (np.full(3, np.nan), float("nan"))
    rows = {name: (measured[name].point, measured[name].depth) if name in measured else missing
            for name in search.landmarks}  # not_found rows stay, flagged
    write_landmark_csv(work / "landmarks.csv", rows, table, flags=flags,
                       provenance=provenance(table=table.label, bone_level=round(float(skull.bone_level), 1),
                                             skin_level=round(levels["skin_level"], 1),
                                             depth="bone level to skin level in the CT along the bone's exposed normal"
                                             if skin is not None else
                                             "not measured: the CT shows no soft tissue (a skull alone)",
                                             frame="CT patient LPS mm", runner="scripts/pdehead_batch.py"))
    return len(found)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--child", nargs=3, metavar=("INPUT", "WORK", "SETTINGS_JSON"), required=True)
    args = p.parse_args(argv)
    input_path, work, settings = args.child
    return _child(input_path, Path(work), json.loads(settings))


if __name__ == "__main__":
    sys.exit(main())
