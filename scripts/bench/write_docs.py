"""Write docs/benchmarks.md from the benchmarks' JSON, without measuring.

Measuring and writing the docs are two steps: a benchmark measures into a JSON of its numbers with the run's
metadata (:func:`save`: commit, machine, date, runs), and its section of docs/benchmarks.md is rendered from
that JSON alone (:func:`write`: the benchmark's own ``markdown`` function, the section replaced by
``md_sections.write_section``). Each benchmark does both in one go by default; ``--from-json FILE`` (its own
flag) or this script renders the section again from a saved JSON::

    python3 scripts/bench/write_docs.py                    # every section from its JSON in docs/
    python3 scripts/bench/write_docs.py smooth --json /tmp/smooth.json --md /tmp/benchmarks.md

(``bench_face.py`` has its own ``--summary-json`` / ``--from-json``, the pattern followed here.)
"""
from __future__ import annotations

import argparse
import datetime as _dt
import importlib
import json
import os
import platform
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from md_sections import keep_sections, write_section  # noqa: E402


@dataclass(frozen=True)
class Section:
    """A benchmark's part of docs/benchmarks.md: the module that measures it, its render function (JSON ->
    markdown) and its JSON in docs/. ``whole``: the render is the whole file (bench.py), the other sections kept."""

    module: str
    render: str
    json_name: str
    whole: bool = False

    @property
    def json_path(self) -> Path:
        return DOCS / self.json_name


#: docs/benchmarks.md's sections a benchmark writes, by name.
SECTIONS: dict[str, Section] = {
    "main": Section("bench", "markdown", "benchmarks.json", whole=True),
    "batch": Section("bench_batch", "markdown", "benchmarks_batch.json"),
    "clinical-scan": Section("bench_clinical_scan", "markdown", "benchmarks_clinical_scan.json"),
    "detail": Section("bench_detail", "markdown", "benchmarks_detail.json"),
    "landmarks": Section("bench_landmarks", "render", "benchmarks_landmarks.json"),
    "live-sliders": Section("bench_live", "markdown", "benchmarks_live.json"),
    "live-face": Section("bench_live", "face_markdown", "benchmarks_live_face.json"),
    "selection": Section("bench_selection", "render", "benchmarks_selection.json"),
    "smooth": Section("bench_smooth", "markdown", "benchmarks_smooth.json"),
    "up-close": Section("bench_smooth", "up_close_markdown", "benchmarks_up_close.json"),
}


def _commit() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("-dirty" if dirty else "")


def metadata(runs) -> dict:
    """The run's metadata a benchmark's JSON carries: commit, machine, date (UTC) and runs per measurement."""
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {"commit": _commit(),
            "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                        "system": platform.platform(), "python": platform.python_version(), "load_average": load},
            "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "runs": runs}


def save(path: Path, result: dict, runs) -> dict:
    """Write ``result`` with the run's :func:`metadata` (key ``"run"``) as JSON to ``path``; returns what was
    written (numpy numbers as plain ones)."""
    out = json.loads(json.dumps({**result, "run": metadata(runs)}, default=_plain))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(out, indent=1) + "\n")
    return out


def _plain(value):
    if hasattr(value, "tolist"):          # numpy scalars and arrays
        return value.tolist()
    return str(value)


def load(path: Path) -> dict:
    return json.loads(Path(path).read_text())


def render(section: str, data: dict) -> str:
    """The markdown of ``section`` from its JSON ``data`` (nothing is measured)."""
    spec = SECTIONS[section]
    return getattr(importlib.import_module(spec.module), spec.render)(data)


def write(section: str, data: dict, md: Path = DOCS / "benchmarks.md") -> str:
    """Render ``section`` from ``data`` into the markdown file ``md`` (its section replaced, the rest kept)."""
    text = render(section, data)
    md = Path(md)
    if SECTIONS[section].whole:
        md.write_text(keep_sections(text, md))
    else:
        write_section(md, section, text)
    return text


def add_arguments(parser, section: str) -> None:
    """``--from-json FILE``: a benchmark's flag to write its section from an earlier run's JSON, no measuring."""
    parser.add_argument("--from-json", type=Path, metavar="FILE",
                        help=f"write the {section!r} section of --md from this JSON (an earlier run's; default "
                             f"docs/{SECTIONS[section].json_name}) without measuring")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("sections", nargs="*", metavar="SECTION",
                   help=f"the sections to write ({', '.join(SECTIONS)}); default: every one whose JSON is in docs/")
    p.add_argument("--json", type=Path, metavar="FILE", help="with one SECTION: its JSON (default: docs/'s)")
    p.add_argument("--md", type=Path, default=DOCS / "benchmarks.md", help="the markdown file (default %(default)s)")
    args = p.parse_args(argv)
    unknown = [n for n in args.sections if n not in SECTIONS]
    if unknown:
        p.error(f"unknown section {', '.join(unknown)} (one of {', '.join(SECTIONS)})")
    if args.json and len(args.sections) != 1:
        p.error("--json needs exactly one SECTION")
    names = args.sections or [n for n, s in SECTIONS.items() if s.json_path.exists()]
    for name in names:
        path = args.json or SECTIONS[name].json_path
        if not path.is_file():
            p.error(f"{name}: no JSON at {path} (run {SECTIONS[name].module}.py first)")
        write(name, load(path), args.md)
        print(f"wrote section {name} of {args.md} from {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
