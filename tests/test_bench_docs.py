"""The benchmarks measure into JSON and docs/benchmarks.md is written from the JSON alone (scripts/bench/write_docs.py).

Every benchmark section is rendered here from a small JSON fixture (tests/fixtures/bench/<section>.json: a run's
JSON trimmed, with sentinel numbers where the section's tables show them), through write_docs and through the
benchmark script's own ``--from-json``: nothing is measured, and the fixture's numbers must appear in the
section's table rows.
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT / "scripts" / "bench"))

import md_sections  # noqa: E402
import write_docs  # noqa: E402

FIXTURES = ROOT / "tests" / "fixtures" / "bench"
OTHER = "<!-- section:someone-else -->\nkept as it was | 1.23 |\n<!-- /section:someone-else -->\n"


def fixture(section: str) -> dict:
    return json.loads((FIXTURES / f"{section}.json").read_text())


def assert_rendered(section: str, text: str) -> None:
    """The fixture's sentinel values are in the section's table rows."""
    rows = [line for line in text.splitlines() if line.startswith("|")]
    assert rows, f"{section}: no table"
    for value in fixture(section)["_fixture"]["rendered"]:
        assert any(value in row for row in rows), f"{section}: {value!r} is in no table row"


@pytest.mark.parametrize("section", sorted(write_docs.SECTIONS))
def test_every_section_renders_from_its_json_alone(section, tmp_path):
    data = fixture(section)
    text = write_docs.render(section, data)
    assert_rendered(section, text)
    md = tmp_path / "benchmarks.md"
    md.write_text("# Benchmarks\n\n" + OTHER)
    write_docs.write(section, data, md)
    written = md.read_text()
    assert OTHER in written                         # the sections of other benchmarks stay
    if write_docs.SECTIONS[section].whole:           # bench.py: the whole file
        assert text.strip() in written
    else:
        assert md_sections.sections(written)[section] == md_sections._block(section, text)


#: How each benchmark script renders its section from a JSON without measuring (its own flags).
SCRIPT_RENDER = {
    "batch": ("bench_batch", lambda j, md: ["--from-json", j, "--md", md]),
    "clinical-scan": ("bench_clinical_scan", lambda j, md: ["--from-json", j, "--md", md]),
    "detail": ("bench_detail", lambda j, md: ["--from-json", j, "--md", md]),
    "landmarks": ("bench_landmarks", lambda j, md: ["--from-json", j, "--md", md]),
    "live-sliders": ("bench_live", lambda j, md: ["--from-json", j, "--md", md]),
    "live-face": ("bench_live", lambda j, md: ["--face", "--from-json", j, "--md", md]),
    "smooth": ("bench_smooth", lambda j, md: ["--from-json", j, "--md", md]),
    "up-close": ("bench_smooth", lambda j, md: ["--up-close", "--from-json", j, "--md", md]),
    "main": ("bench", lambda j, md: ["--render-only", "--out", j, "--md", md]),
}


@pytest.mark.parametrize("section", sorted(SCRIPT_RENDER))
def test_each_benchmark_writes_its_section_from_json_without_measuring(section, tmp_path, monkeypatch):
    import importlib
    module_name, argv = SCRIPT_RENDER[section]
    module = importlib.import_module(module_name)
    for name in ("run", "run_batch", "bench_dataset", "bench_face_dataset", "up_close", "run_phantom",
                 "run_cthead", "run_cli", "make_scan"):
        if hasattr(module, name):                    # measuring would fail the test
            monkeypatch.setattr(module, name, lambda *a, **k: pytest.fail("measured"))
    if hasattr(module, "Bench"):
        monkeypatch.setattr(module, "Bench", lambda *a, **k: pytest.fail("measured"))
    source = tmp_path / "run.json"
    source.write_text((FIXTURES / f"{section}.json").read_text())
    md = tmp_path / "benchmarks.md"
    md.write_text(OTHER)
    assert module.main([str(a) for a in argv(source, md)]) in (0, None)
    written = md.read_text()
    assert OTHER in written
    body = written if section == "main" else md_sections.sections(written)[section]
    assert_rendered(section, body)


def test_selection_renders_with_the_figure_name_it_recorded():
    data = fixture("selection")
    text = write_docs.render("selection", data)
    assert_rendered("selection", text)
    assert "selection_accuracy.png" in text
    assert "other_name.png" in write_docs.render("selection", {**data, "figure": "other_name.png"})


def test_every_benchmark_that_writes_the_docs_goes_through_write_docs():
    """No benchmark writes docs/benchmarks.md from measured numbers directly (bench_face.py keeps its own
    --summary-json / --from-json, the pattern this follows); each section has a fixture."""
    bench = ROOT / "scripts" / "bench"
    for path in sorted(bench.glob("bench*.py")):
        text = path.read_text()
        if path.name == "bench_face.py":
            continue
        assert "write_section(" not in text and "keep_sections(" not in text, path.name
        if "write_docs.write(" in text:
            assert any(s.module == path.stem for s in write_docs.SECTIONS.values()), path.name
    assert {p.stem for p in FIXTURES.glob("*.json")} == set(write_docs.SECTIONS)


def test_save_records_the_runs_metadata_and_plain_numbers(tmp_path):
    out = write_docs.save(tmp_path / "x.json", {"value": np.float32(1.5), "n": np.int64(3),
                                                "rows": np.arange(3)}, runs=5)
    again = json.loads((tmp_path / "x.json").read_text())
    assert again == out and again["value"] == 1.5 and again["n"] == 3 and again["rows"] == [0, 1, 2]
    run = again["run"]
    assert run["runs"] == 5 and run["machine"]["cores"] >= 1 and run["machine"]["cpu"]
    assert re.fullmatch(r"[0-9a-f]{7,}(-dirty)?|unknown", run["commit"]), run["commit"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", run["date"])


def test_write_docs_command_line(tmp_path, capsys):
    md = tmp_path / "b.md"
    md.write_text(OTHER)
    assert write_docs.main(["batch", "--json", str(FIXTURES / "batch.json"), "--md", str(md)]) == 0
    assert_rendered("batch", md_sections.sections(md.read_text())["batch"])
    with pytest.raises(SystemExit) as exc:
        write_docs.main(["no-such-section", "--md", str(md)])
    assert exc.value.code == 2 and "no-such-section" in capsys.readouterr().err
