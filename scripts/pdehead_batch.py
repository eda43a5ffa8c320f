#!/usr/bin/env python3
"""Many studies at once: batch runs on Dask, and population depth tables from their landmarks.

Examples::

    python3 scripts/pdehead_batch.py run archive/*/ --out batch/ --skull            # local cluster, a worker per core
    python3 scripts/pdehead_batch.py run @studies.txt --out batch/ --workers 8
    python3 scripts/pdehead_batch.py run @studies.txt --out batch/ --scheduler tcp://10.0.0.5:8786
    python3 scripts/pdehead_batch.py run a/ b/ --out batch/ --workers 0             # serial, no Dask
    python3 scripts/pdehead_batch.py depth-table batch/ --out table.csv --by sex --by age

``run`` gives every study its own folder ``DIR/<study_id>/`` (``scripts/batch_study.py`` says what is in
it) and writes ``DIR/summary.csv`` (``study_id,input,status,error,seconds,n_landmarks,warnings``). The
workers run the engine only (no Blender). A study that fails is recorded with its one-line error and
never stops the batch; a re-run skips the studies whose input and settings are unchanged. Workers read
the inputs from paths they can see and write under ``--out``: only paths and small records travel
through the scheduler, so ``--out`` must be a folder every worker can write (a shared file system on a
cluster).

``depth-table`` turns a batch's landmark depths into a table the add-on imports
(``landmark,mean_mm,sd_mm,n``), optionally one per sex and/or age group (18-29, 30-44, 45-59, 60+;
PatientAge, else PatientBirthDate and StudyDate). Depths outside 0 < d <= 60 mm and landmarks not
flagged ``ok`` are left out and counted in ``<table>_excluded.csv`` beside it.

Exit status: 0 when every study is ``ok`` or recorded as ``failed``; 2 for bad arguments; 1 for an
internal error; 130 on Ctrl-C (the studies already finished stay, the summary lists them).
Dask and distributed are headless-only dependencies (requirements.txt); the add-on never imports them.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from collections import defaultdict
from datetime import date
from pathlib import Path

import _cli_flags  # (scripts/ on sys.path: the flags of study settings, from the defaults table)
import _common  # (the dev shim for the engine, the loader options)
import batch_study

PROG = "pdehead_batch"
SUMMARY_COLUMNS = ["study_id", "input", "status", "error", "seconds", "n_landmarks", "warnings"]
TABLE_COLUMNS = ["landmark", "mean_mm", "sd_mm", "n"]
#: Depths a population table keeps (mm): a landmark depth outside this is a failed measurement.
DEPTH_RANGE_MM = (0.0, 60.0)
AGE_GROUPS = ((18, 29, "18-29"), (30, 44, "30-44"), (45, 59, "45-59"), (60, 200, "60+"))


class CLIError(Exception):
    def __init__(self, message: str, code: int = 2):
        super().__init__(message)
        self.code = code


def say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- arguments
def parsers() -> tuple[argparse.ArgumentParser, argparse.ArgumentParser]:
    """The command line's parser and its ``run`` subcommand's (the tests read the flags' declarations there)."""
    p = argparse.ArgumentParser(prog=PROG, description="Batch runs and population depth tables (headless, Dask).")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run many studies (engine only) into DIR/<study_id>/ and DIR/summary.csv")
    r.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="study folders or files (DICOM, NIfTI, image or raw stacks: see the loader options), or "
                        "@list.txt with one per line")
    r.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder (created if missing)")
    where = r.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help=f"local Dask workers (processes); default the cores ({os.cpu_count()}); 0 runs serially "
                            "without Dask")
    where.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler, e.g. tcp://host:8786")
    r.add_argument("--skull", action="store_true",
                   help="also the bone skull (skull.stl), automatic landmarks and their depths (landmarks.csv)")
    for setting in ("patches", "samples", "selection"):   # the study settings' flags: from the defaults table
        _cli_flags.add(r, setting)
    r.add_argument("--time-limit", type=float, default=batch_study.DEFAULT_TIME_LIMIT_S, metavar="S",
                   help=f"per-study wall-time limit in seconds; default {batch_study.DEFAULT_TIME_LIMIT_S:g}")
    r.add_argument("--memory-limit", type=float, default=batch_study.DEFAULT_MEMORY_LIMIT_MB, metavar="MB",
                   help=f"per-study memory limit (resident, MB); default {batch_study.DEFAULT_MEMORY_LIMIT_MB:g}")
    r.add_argument("--force", action="store_true", help="redo every study, also those that are current")
    r.add_argument("--summary-json", type=Path, metavar="FILE", help="also write the run's summary as JSON")
    _common.add_loader_arguments(r)      # pdehead.py's loader options, the same definition: every study is read so
    t = sub.add_parser("depth-table", help="a population depth table from a batch's landmarks")
    t.add_argument("batch", type=Path, metavar="DIR", help="a batch output folder (of 'run --skull')")
    t.add_argument("--out", type=Path, required=True, metavar="TABLE.csv", help="the table to write")
    t.add_argument("--by", action="append", choices=["sex", "age"], default=[],
                   help="split by DICOM PatientSex and/or age group (repeatable)")
    return p, r


def parse_args(argv=None) -> argparse.Namespace:
    p, r = parsers()
    args = p.parse_args(argv)
    if args.command == "run":
        if args.workers is not None and args.workers < 0:
            raise CLIError("--workers must be 0 (serial) or more")
        _cli_flags.check(r, args, _usage_error)
        if not (args.time_limit > 0 and args.memory_limit > 0):
            raise CLIError("--time-limit and --memory-limit must be positive")
        _common.check_loader_args(_usage_error, args)
    return args


def _usage_error(message: str):
    raise CLIError(message)


def expand_inputs(items: list[str]) -> list[str]:
    """INPUT arguments with ``@list.txt`` expanded (one path a line; blank and ``#`` lines skipped; paths
    relative to the list's folder); duplicates (the same absolute path) kept once."""
    out: list[str] = []
    for item in items:
        if item.startswith("@"):
            listing = Path(item[1:])
            try:
                lines = listing.read_text().splitlines()
            except OSError as exc:
                raise CLIError(f"{listing}: cannot read the input list ({exc.strerror})") from None
            for line in lines:
                line = line.strip()
                if line and not line.startswith("#"):
                    path = Path(line).expanduser()
                    out.append(str(path if path.is_absolute() else listing.parent / path))
        else:
            out.append(item)
    seen, unique = set(), []
    for item in out:
        key = str(Path(item).expanduser().absolute())
        if key not in seen:
            seen.add(key)
            unique.append(str(Path(item).expanduser().absolute()))
    if not unique:
        raise CLIError("no inputs (an empty @list?)")
    return unique


# --------------------------------------------------------------------------- run
def study_settings(args) -> dict:
    """What a study's result depends on (besides its input); a change redoes the study."""
    return {"patches": int(args.patches), "samples": int(args.samples), "selection": str(args.selection),
            "skull": bool(args.skull), "loader": _common.engine_loader_options(args)}


class Progress:
    """done / failed / running, rate and time left, one stderr line per finished study."""

    def __init__(self, total: int):
        self.total, self.done, self.failed, self.skipped = total, 0, 0, 0
        self.t0 = time.monotonic()

    def update(self, record: dict, running: int) -> None:
        self.done += 1
        self.failed += record["status"] == "failed"
        self.skipped += bool(record.get("skipped"))
        elapsed = time.monotonic() - self.t0
        worked = self.done - self.skipped
        rate = worked / elapsed * 60 if elapsed > 0 and worked else 0.0
        left = (self.total - self.done) / (rate / 60) if rate > 0 else float("nan")
        what = "unchanged, skipped" if record.get("skipped") else (
            f"{record['status']} in {record['seconds']:.1f} s" + (f": {record['error']}" if record["error"] else ""))
        eta = f", about {_duration(left)} left" if math.isfinite(left) else ""
        say(f"[{self.done}/{self.total}] {record['study_id']}: {what} | done {self.done - self.failed}, "
            f"failed {self.failed}, running {running}, {rate:.1f} studies/min{eta}")


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def run_serial(inputs, out: Path, settings: dict, args, progress: Progress, records: list[dict]) -> None:
    for i, path in enumerate(inputs):
        rec = batch_study.run_study(path, str(out), settings, args.time_limit, args.memory_limit, args.force)
        records.append(rec)
        progress.update(rec, running=min(1, len(inputs) - i - 1))


def run_dask(inputs, out: Path, settings: dict, args, progress: Progress, records: list[dict]) -> None:
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if args.scheduler:
        client = Client(args.scheduler, timeout="30s")
        client.upload_file(batch_study.__file__)  # workers elsewhere get this runner module
    else:
        n = args.workers or os.cpu_count() or 1
        # one single-threaded process per worker: a study is single-threaded numpy; the per-study
        # memory limit is ours (batch_study), so Dask's own memory management is off
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, memory_limit=0,
                               dashboard_address=None, silence_logs=40)
        client = Client(cluster)
    try:
        futures = [client.submit(batch_study.run_study, path, str(out), settings, args.time_limit,
                                 args.memory_limit, args.force, key=f"study-{batch_study.study_id(path)}",
                                 pure=False, retries=0)
                   for path in inputs]
        by_key = {f.key: i for i, f in enumerate(futures)}
        running = len(futures)
        for fut in as_completed(futures):
            running -= 1
            i = by_key[fut.key]
            try:
                rec = fut.result()
            except Exception as exc:  # a worker died (or the runner raised): recorded, the batch goes on
                rec = {"study_id": batch_study.study_id(inputs[i]), "input": inputs[i], "status": "failed",
                       "error": f"worker error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
                       "seconds": 0.0, "n_landmarks": 0, "warnings": [], "skipped": False}
            records.append(rec)
            progress.update(rec, running)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def write_summary(out: Path, records: list[dict]) -> Path:
    """``DIR/summary.csv`` in input order, written whole (a temporary file renamed into place)."""
    path = out / "summary.csv"
    tmp = out / ".summary.csv.tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(SUMMARY_COLUMNS)
        for r in records:
            w.writerow([r["study_id"], r["input"], r["status"], r["error"], f"{r['seconds']:.2f}",
                        r["n_landmarks"], " | ".join(r.get("warnings", []))])
    os.replace(tmp, path)
    return path


def cmd_run(args) -> int:
    inputs = expand_inputs(args.inputs)
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise CLIError(f"--out {out}: cannot write there ({exc.strerror})") from None
    settings = study_settings(args)
    serial = args.workers == 0 and not args.scheduler
    where = "serially" if serial else (f"on the scheduler {args.scheduler}" if args.scheduler
                                       else f"on a local cluster of {args.workers or os.cpu_count()} workers")
    say(f"{len(inputs)} studies {where} -> {out}")
    if batch_study.remove_stale_work(out, older_than_s=2 * args.time_limit):
        say(f"removed work folders left in {out} by an interrupted run")
    progress = Progress(len(inputs))
    t0 = time.monotonic()
    records: list[dict] = []
    order = {path: i for i, path in enumerate(inputs)}
    try:
        (run_serial if serial else run_dask)(inputs, out, settings, args, progress, records)
    finally:  # also on Ctrl-C: the summary lists the studies that finished (in input order)
        records.sort(key=lambda r: order.get(r["input"], len(order)))
        summary = write_summary(out, records)
    ok = sum(r["status"] == "ok" for r in records)
    skipped = sum(bool(r.get("skipped")) for r in records)
    wall = time.monotonic() - t0
    print(f"{ok} ok, {len(records) - ok} failed, {skipped} unchanged (skipped) of {len(records)} studies "
          f"in {wall:.1f} s; summary: {summary}")
    if args.summary_json:
        _write_json(args.summary_json, {"studies": len(records), "ok": ok, "failed": len(records) - ok,
                                        "skipped": skipped, "seconds": round(wall, 2), "summary_csv": str(summary),
                                        "records": records})
    return 0


def _write_json(path: Path, data) -> None:
    try:
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(json.dumps(data, indent=2) + "\n")
        os.replace(tmp, path)
    except OSError as exc:
        raise CLIError(f"--summary-json {path}: cannot write ({exc.strerror})") from None


# --------------------------------------------------------------------------- depth table
def age_years(subject: dict) -> float | None:
    """Age in years from DICOM PatientAge ('035Y', '018M', '020W', '100D'), else BirthDate and StudyDate."""
    age = (subject.get("age") or "").strip().upper()
    if len(age) >= 2 and age[:-1].isdigit() and age[-1] in "YMWD":
        return int(age[:-1]) / {"Y": 1, "M": 12, "W": 52.1775, "D": 365.25}[age[-1]]
    born, seen = subject.get("birth_date") or "", subject.get("study_date") or ""
    try:
        b = date(int(born[:4]), int(born[4:6]), int(born[6:8]))
        s = date(int(seen[:4]), int(seen[4:6]), int(seen[6:8]))
    except ValueError:
        return None
    return (s - b).days / 365.25


def age_group(years: float | None) -> str:
    if years is None:
        return "unknown"
    for lo, hi, name in AGE_GROUPS:
        if lo <= years < hi + 1:
            return name
    return "under-18"


def group_of(subject: dict, by: list[str]) -> str:
    parts = []
    if "sex" in by:
        parts.append({"M": "male", "F": "female", "O": "other"}.get((subject.get("sex") or "").upper(), "unknown"))
    if "age" in by:
        parts.append(age_group(age_years(subject)))
    return "_".join(parts) or "all"


def collect_depths(batch: Path, by: list[str]):
    """{group: {landmark: [depth]}} of the usable depths, and the left-out rows with their reason."""
    kept: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    excluded: list[dict] = []
    studies = 0
    for study in sorted(p for p in batch.iterdir() if p.is_dir() and not p.name.startswith(".")):
        try:
            result = json.loads((study / batch_study.RESULT_FILE).read_text())
            meta = json.loads((study / batch_study.SETTINGS_FILE).read_text())
        except (OSError, ValueError):
            continue
        if result.get("status") != "ok" or not (study / "landmarks.csv").exists():
            continue
        studies += 1
        group = group_of(meta.get("subject", {}), by)
        with open(study / "landmarks.csv", newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].startswith("#")]
        header, rows = [h.strip().lower() for h in rows[0]], rows[1:]
        col = {name: i for i, name in enumerate(header)}
        for row in rows:
            name = row[col["landmark"]]
            flag = row[col["flag"]] if "flag" in col and col["flag"] < len(row) else "ok"
            text = row[col["depth_mm"]] if col["depth_mm"] < len(row) else ""
            depth = float(text) if text.strip() else float("nan")
            reason = ""
            if flag != "ok":
                reason = f"flag {flag}"
            elif not (math.isfinite(depth) and DEPTH_RANGE_MM[0] < depth <= DEPTH_RANGE_MM[1]):
                reason = "depth outside 0 < d <= 60 mm" if math.isfinite(depth) else "no depth measured"
            if reason:
                excluded.append({"study_id": study.name, "group": group, "landmark": name,
                                 "depth_mm": text, "flag": flag, "reason": reason})
            else:
                kept[group][name].append(depth)
    return kept, excluded, studies


def cmd_depth_table(args) -> int:
    batch: Path = args.batch
    if not batch.is_dir():
        raise CLIError(f"{batch}: not a batch output folder")
    kept, excluded, studies = collect_depths(batch, args.by)
    if studies == 0:
        raise CLIError(f"{batch}: no finished study with landmarks.csv (run the batch with --skull)")
    out: Path = args.out
    written = []
    for group in sorted(kept):
        path = out if group == "all" else out.with_name(f"{out.stem}_{group}{out.suffix or '.csv'}")
        rows = []
        for name in sorted(kept[group]):
            d = kept[group][name]
            sd = float(_stdev(d)) if len(d) > 1 else float("nan")
            rows.append([name, f"{sum(d) / len(d):.2f}", "" if not math.isfinite(sd) else f"{sd:.2f}", len(d)])
        _write_csv(path, [f"# depth table from {studies} studies of the batch {batch.resolve().name}"
                          f"{'' if group == 'all' else f', group {group}'}; landmarks flagged ok, 0 < d <= 60 mm"],
                   TABLE_COLUMNS, rows)
        written.append(path)
        print(f"{path}: {len(rows)} landmarks, n {min((r[3] for r in rows), default=0)}-"
              f"{max((r[3] for r in rows), default=0)}")
    ex_path = out.with_name(f"{out.stem}_excluded.csv")
    _write_csv(ex_path, [], ["study_id", "group", "landmark", "depth_mm", "flag", "reason"],
               [[e[k] for k in ("study_id", "group", "landmark", "depth_mm", "flag", "reason")] for e in excluded])
    print(f"{ex_path}: {len(excluded)} depths left out")
    return 0


def _stdev(values: list[float]) -> float:
    m = sum(values) / len(values)
    return math.sqrt(sum((v - m) ** 2 for v in values) / (len(values) - 1))


def _write_csv(path: Path, comments: list[str], header: list[str], rows: list[list]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "w", newline="") as fh:
            for c in comments:
                fh.write(c + "\n")
            w = csv.writer(fh)
            w.writerow(header)
            w.writerows(rows)
        os.replace(tmp, path)
    except OSError as exc:
        raise CLIError(f"--out {path}: cannot write ({exc.strerror})") from None


def main(argv=None) -> int:
    try:
        args = parse_args(argv)
        return cmd_run(args) if args.command == "run" else cmd_depth_table(args)
    except CLIError as exc:
        say(f"{PROG}: error: {exc}")
        return exc.code
    except KeyboardInterrupt:
        say(f"{PROG}: interrupted (Ctrl-C); finished studies are kept")
        return 130


if __name__ == "__main__":
    sys.exit(main())
