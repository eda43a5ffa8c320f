"""Smoke test of scripts/bench/bench.py: the --quick logic on the phantom only, and its STL writer.

No wall-clock assertions: only that the JSON has the expected structure and sane values
(counts, Jaccard, byte sizes, distances) and that the markdown report is written.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))           # _common
sys.path.insert(0, str(ROOT / "scripts" / "bench"))  # the benchmarks

import bench  # noqa: E402


@pytest.fixture(scope="module")
def quick_phantom(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bench")
    json_path, md_path = tmp / "bench.json", tmp / "bench.md"
    assert bench.main(["--quick", "--datasets", "phantom", "--repeats", "1",
                       "--out", str(json_path), "--md", str(md_path)]) == 0
    return json.loads(json_path.read_text()), md_path.read_text()


def test_top_level_keys(quick_phantom):
    out, _ = quick_phantom
    assert {"command", "mode", "repeats", "machine", "datasets", "targets", "notes", "total_s"} <= set(out)
    assert out["mode"] == "quick" and out["repeats"] == 1
    m = out["machine"]
    assert m["cores"] >= 1 and m["cpu"] and m["python"].startswith("3.")
    assert m["numpy"] == np.__version__ and m["scikit-image"] and m["date"]
    assert any("QUICK" in n for n in out["notes"])
    assert list(out["datasets"]) == ["phantom"]


def test_phantom_stages(quick_phantom):
    out, _ = quick_phantom
    ph = out["datasets"]["phantom"]
    errors = {k: v["error"] for k, v in ph.items() if isinstance(v, dict) and "error" in v}
    assert not errors, errors
    assert ph["load"]["shape"] == [100, 128, 128]

    seg = ph["segmentation"]
    assert seg["ours"]["time"]["median_s"] > 0 and len(seg["ours"]["time"]["runs_s"]) == 1
    assert seg["reference"].startswith("exact phantom truth")
    assert 0.95 <= seg["ours"]["jaccard"] <= 1.0
    peer = seg["peer"]
    assert peer["subset"] is True and peer["slices"] == len(peer["slice_indices"]) == 3
    assert 0.0 <= peer["slice_jaccard_mean_raw"] <= 1.0 and 0.0 <= peer["slice_jaccard_mean_cleaned"] <= 1.0
    assert peer["all_head_slices_s"] == pytest.approx(peer["total_s"] / 3 * seg["head_slices"])
    assert seg["ratio"] == pytest.approx(peer["all_head_slices_s"] / seg["ours"]["median_s"])
    per = seg["per_slice_jaccard"]
    assert len(per["slices"]) == len(per["ours"]) == seg["head_slices"] > 50
    assert min(per["ours"]) > 0.8 and peer["ours_slice_jaccard_mean_same_slices"] > 0.8

    bd = ph["boundaries"]
    idx = bd["slice_indices"]
    assert bd["patches"] == 10 and bd["samples"] == 256 and len(idx) == 31 and idx == sorted(set(idx))

    su = ph["surface"]
    # capped tube with a dome: the crown's pole, and the bottom closed by a flat disc of rings (issue 21)
    assert 39 * 60 + 2 < su["ours"]["vertices"] < 39 * 60 + 2 + 60 * 40
    assert su["peer"]["faces"] > 20 * su["ours"]["faces"]
    assert su["ratio_engine"] > 0 and su["ratio_total"] > 0
    assert su["ours"]["blender"]["polygons"] == su["ours"]["faces"]
    assert su["peer"]["blender"]["polygons"] == su["peer"]["faces"]
    assert len(su["peer"]["engine"]["runs_s"]) >= 1 and len(su["ours"]["blender"]["runs_s"]) == 1
    assert su["ours"]["total_median_s"] == pytest.approx(
        su["ours"]["engine_with_caps"]["median_s"] + su["ours"]["blender"]["median_s"])

    st = ph["storage"]
    assert st["peer"]["bytes"] == 84 + 50 * st["peer"]["triangles"]
    assert st["peer"]["triangles"] == su["peer"]["faces"]
    assert 0 < st["ours"]["bytes"] < st["peer"]["bytes"] / 20
    assert st["ours"]["roundtrip_max_error_mm"] < 1.0
    assert st["ratio"] == pytest.approx(st["peer"]["bytes"] / st["ours"]["bytes"])

    fid = ph["fidelity"]["series"]
    assert [r["t"] for r in fid] == [10]
    assert 0 < fid[0]["mean"] < 3.0 and fid[0]["mean"] <= fid[0]["p95"] <= fid[0]["max"]

    wf = ph["wfield"]
    assert wf["ours"]["grid"] == [100, 128, 128] and wf["ours"]["inside_voxels"] > 10_000
    assert wf["vdb"]["bytes"] > 1000


def test_markdown_report(quick_phantom):
    out, md = quick_phantom
    for heading in ("## Machine", "## Targets", "## Speed", "## Storage", "## Fidelity", "## Memory"):
        assert heading in md
    assert "| phantom | segmentation |" in md and "marching cubes" in md
    # the phantom alone gives no CThead target rows
    assert all("CThead" not in t["name"] for t in out["targets"])


def test_timed_median():
    calls = []
    stats, result = bench.timed(lambda: calls.append(1) or len(calls), 5)
    assert result == 5 and len(stats["runs_s"]) == 5
    assert stats["min_s"] <= stats["median_s"] <= max(stats["runs_s"])


def test_bench_smooth_quick_smoke(tmp_path):
    """scripts/bench/bench_smooth.py --quick on CThead t=10: the issue-8 measures, the peers, the markdown section."""
    import bench_smooth
    md = tmp_path / "benchmarks.md"
    md.write_text("# Benchmarks\n\nother text\n")
    out = tmp_path / "smooth.json"
    assert bench_smooth.main(["--quick", "--repeats", "1", "--json", str(out), "--md", str(md)]) == 0
    res = json.loads(out.read_text())
    row = res["datasets"]["cthead"][0]
    c2, paper = row["c2"], row["paper"]
    assert row["t"] == 10 and c2["folds"] == 0
    assert c2["crease_p95_deg"] < 2.0 < paper["crease_p95_deg"]
    assert 0.3 < c2["mean"] < 0.7 and c2["p95"] < 2.5
    sp = res["speed"]
    assert sp["marching_cubes_triangles"] > 100_000 and sp["flying_edges_triangles"] > 100_000
    assert sp["ours_ms"] > 0 and sp["flying_edges_ms"] > 0
    text = md.read_text()
    assert "other text" in text and "<!-- section:smooth -->" in text and "flying" in text.lower()
    # a second run replaces its section instead of adding one
    assert bench_smooth.main(["--quick", "--repeats", "1", "--json", str(out), "--md", str(md)]) == 0
    assert md.read_text().count("<!-- section:smooth -->") == 1


def test_clinical_scan_sums_every_printed_step():
    """bench_clinical_scan.py sums every step the CLI prints (the solid's CT table included), never ``total``,
    and stops on a step it does not know rather than leave it out of the sum."""
    import bench_clinical_scan
    stdout = ("Info: ...\ntimings (s):\n  import        0.400\n  segment       5.000\n  boundaries    2.500\n"
              "  pde_solve     0.004\n  surface       0.250\n  ct_table      0.300\n  solid         0.120\n"
              "  w_field       0.500\n  volume        1.000\n  total        10.500\nwrote x.blend\n")
    steps = bench_clinical_scan.step_times(stdout)
    assert steps["ct_table"] == 0.3 and steps["total"] == 10.5 and len(steps) == 10
    assert bench_clinical_scan.sum_of_steps(steps) == pytest.approx(10.074)
    with pytest.raises(SystemExit, match="new_step"):
        bench_clinical_scan.sum_of_steps(dict(steps, new_step=1.0))


def test_clinical_scan_surface_against_the_reference_mask(phantom_seg):
    """The benchmark's 0.2 mm check (issue 20): ~0 for the same mask (the sampled measure's own floor, a
    point's nearest triangle missed among its candidates: ~0.003 mm), about the shift for a mask moved
    2 voxels along x (a surface 2 mm to the side on the phantom's 1 mm pixels)."""
    import bench_clinical_scan
    same = bench_clinical_scan.surface_against_reference(phantom_seg, phantom_seg.mask)
    assert same["mean"] < 0.01
    moved = bench_clinical_scan.surface_against_reference(phantom_seg, np.roll(phantom_seg.mask, 2, axis=2))
    dx = float(phantom_seg.ct.spacing[2])
    assert 0.5 * dx < moved["mean"] < 2.0 * 2 * dx and moved["max"] >= 1.5 * dx


def test_clinical_scan_judges_reopen_and_ctrl_c():
    """The reopen and Ctrl-C rows judge the worst case and the clean exit, not the first or the median."""
    import bench_clinical_scan
    cancels = [{"at_s": 3.0, "finished_before": False, "latency_s": 0.4, "exit_code": 130, "output_left": False},
               {"at_s": 6.0, "finished_before": False, "latency_s": 0.9, "exit_code": 130, "output_left": False},
               {"at_s": 10.5, "finished_before": True}]
    reopen = {"first_cutaway_s": 0.5, "first_pde_change_s": 2.0, "cutaway_error": "", "pde_change_error": ""}
    rows = bench_clinical_scan._reopen_and_cancel_rows({"reopen": reopen, "cancels": cancels})
    assert len(rows) == 2 and all(row.endswith("**met** |") for row in rows)
    assert "0.90 s (worst)" in rows[1]
    slow = [dict(cancels[0]), dict(cancels[1], latency_s=1.3)]
    assert bench_clinical_scan._reopen_and_cancel_rows({"cancels": slow})[0].endswith("**NOT met** |")
    left = [dict(cancels[0], output_left=True)]
    assert bench_clinical_scan._reopen_and_cancel_rows({"cancels": left})[0].endswith("**NOT met** |")
    wrong_exit = [dict(cancels[0], exit_code=1)]
    assert bench_clinical_scan._reopen_and_cancel_rows({"cancels": wrong_exit})[0].endswith("**NOT met** |")
    slow_reopen = dict(reopen, first_pde_change_s=3.5)
    assert bench_clinical_scan._reopen_and_cancel_rows({"reopen": slow_reopen})[0].endswith("**NOT met** |")
