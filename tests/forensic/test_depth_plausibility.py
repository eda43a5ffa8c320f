"""Plausible ``ok`` depths: a landmark depth is ``ok`` only where the ray from the bone meets the skin within 1.5x
the distance to the nearest skin, not within two voxels of the scan's edge, and within the depth table's mean
+- 3 SD; otherwise ``uncertain`` with the reason. A batch depth table over CThead, GE and the phantom then has
every mean within the T-Table's mean +- 3 SD (before: nasion 13.1, rhinion 7.9, suborbital L 18.9 mm outside)."""
from __future__ import annotations

import csv
import io
import json
import sys
from contextlib import redirect_stdout
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.special import erfc
from skimage.measure import marching_cubes

from pdehead_addon.core.ct_volume import CTVolume
from pdehead_addon.core.mesh import Mesh
from pdehead_addon.forensic.depth_on_ct import measure_landmark_depths
from pdehead_addon.forensic.depth_table import DepthEntry, DepthTable, default_table

ROOT = Path(__file__).resolve().parents[2]


def _slab_scene(top: float = 40.0):
    """An 8 mm bone slab (|z| < 4, 60 x 60 mm, a round opening of radius 12 mm) under soft tissue up to z = 10 mm,
    on a 1 mm grid from -40 mm to ``top`` in z; the skin mesh a plane at z = 12 (a PDE skin that smooths over)."""
    ax = np.arange(-40.0, 41.0)
    az = np.arange(-40.0, top + 1.0)
    z, y, x = np.meshgrid(az, ax, ax, indexing="ij")
    bone = np.minimum.reduce([30 - np.abs(x), 30 - np.abs(y), 4 - np.abs(z), np.hypot(x, y) - 12])
    edge = lambda d: 0.5 * erfc(-d / (np.sqrt(2.0) * 0.8))                                      # noqa: E731
    hu = -1000.0 + 1040.0 * edge(10.0 - z) + 1060.0 * edge(bone)
    ct = CTVolume(hu.astype(np.float32), (1.0, 1.0, 1.0), origin=(ax[0], ax[0], az[0]), direction=np.eye(3))
    seg = SimpleNamespace(hu=ct.data, ct=ct, bone_level=570.0, c2=40.0, meta={"has_skin": True,
                                                                               "histogram": {"bone_mode": 1100.0}})
    g = np.arange(-40.0, 41.0, 4.0)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 12.0)], 1)
    n = len(g)
    q = np.array([[i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1] for i in range(n - 1) for j in range(n - 1)]
                 + [[i * n + j, (i + 1) * n + j + 1, i * n + j + 1] for i in range(n - 1) for j in range(n - 1)])
    skin = Mesh(vertices=verts, quads=np.zeros((0, 4), np.int64), triangles=q)
    xs, ys, zs = np.meshgrid(ax, ax, ax, indexing="ij")
    solid = (np.abs(xs) < 30) & (np.abs(ys) < 30) & (np.abs(zs) < 4) & (xs ** 2 + ys ** 2 > 12 ** 2)
    v, f, _, _ = marching_cubes(solid.astype(np.float32), 0.5)
    slab = Mesh(vertices=v + ax[0], quads=np.zeros((0, 4), np.int64), triangles=f[:, ::-1])
    head = (z < 10.0)
    return ct, seg, skin, slab, head, (z, y, x)


@pytest.fixture(scope="module")
def scene():
    return _slab_scene()


LANDMARKS = {"Glabella": np.array([22.0, 10.0, 4.0]), "Vertex": np.array([-20.0, -15.0, 4.0])}


def test_a_plausible_depth_stays_ok(scene):
    ct, seg, skin, slab, head, _ = scene
    got = measure_landmark_depths(LANDMARKS, slab, skin, seg, head_mask=head, table=default_table())
    for name, m in got.items():
        assert m.trusted and m.depth == pytest.approx(6.0, abs=0.1), (name, m.evidence)


def test_a_ray_along_the_face_is_uncertain(scene):
    """The skin 2.5 mm beside the bone point (a notch of air in the head mask) while the ray meets it 6 mm up:
    more than 1.5x the nearest skin."""
    ct, seg, skin, slab, head, (z, y, x) = scene
    notched = head & ~((np.abs(x - 25.0) < 1.0) & (np.abs(y - 10.0) < 3.0) & (z > 4.5))
    got = measure_landmark_depths(LANDMARKS, slab, skin, seg, head_mask=notched)
    g = got["Glabella"]
    assert not g.trusted and "more than 1.5 x the nearest skin's" in g.evidence, g.evidence
    nearest = float(g.evidence.split("nearest skin's ")[1].split(" mm")[0])
    assert 1.5 <= nearest <= 3.5 and g.depth == pytest.approx(6.0, abs=0.1)
    assert got["Vertex"].trusted, got["Vertex"].evidence


def test_a_depth_at_the_scans_edge_is_uncertain():
    """The scan ends 1 mm above the skin (the skin crossing within two voxels of the last slice)."""
    ct, seg, skin, slab, head, _ = _slab_scene(top=11.0)
    got = measure_landmark_depths(LANDMARKS, slab, skin, seg, head_mask=head)
    for name, m in got.items():
        assert not m.trusted and "within 2 voxels of the scan's edge" in m.evidence, (name, m.evidence)
    # a tilted slab's border (the coverage mask): the same
    ct2, seg2, skin2, slab2, head2, (z, y, x) = _slab_scene()
    ct2.coverage = z < 11.0
    got = measure_landmark_depths(LANDMARKS, slab2, skin2, seg2, head_mask=head2)
    assert all(not m.trusted and "scanned slab's border" in m.evidence for m in got.values())


def test_a_depth_outside_the_tables_three_sd_is_uncertain(scene):
    ct, seg, skin, slab, head, _ = scene
    table = DepthTable(entries={"Glabella": DepthEntry("Glabella", 20.0, 4.0),      # 8-32 mm: 6 is outside
                                "Vertex": DepthEntry("Vertex", 5.0, None)}, name="test")  # no SD: not checked
    got = measure_landmark_depths(LANDMARKS, slab, skin, seg, head_mask=head, table=table)
    assert not got["Glabella"].trusted
    assert "outside the table's mean +- 3 SD" in got["Glabella"].evidence and "8.0-32.0 mm" in got["Glabella"].evidence
    assert got["Vertex"].trusted


# --------------------------------------------------------------------------- the batch over the three heads
@pytest.fixture(scope="module")
def batch_over_three_heads(tmp_path_factory, cthead_ct, cthead_seg, ge_ct, ge_seg, phantom, phantom_seg):
    """The batch's study step (scripts/batch_study.py, the child's skull outputs) on CThead, GE and the phantom,
    in this process, with the batch's default settings; then its depth-table command."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import batch_study
    import pdehead_addon as eng
    import pdehead_batch
    from pdehead_addon import defaults as D

    out = tmp_path_factory.mktemp("batch3")
    for name, ct, seg in (("cthead", cthead_ct, cthead_seg), ("ge", ge_ct, ge_seg), ("phantom", phantom.ct,
                                                                                    phantom_seg)):
        patches, _ = eng.patches_for_scan(seg, D.PATCHES.default)
        bset = eng.extract_boundaries(seg, patches=patches, samples=D.SAMPLES.default, selection=D.SELECTION.default)
        work = out / name
        work.mkdir()
        log = io.StringIO()
        with redirect_stdout(log):
            batch_study._skull_outputs(eng, ct, seg, bset, work, {"skull": True})
        (work / batch_study.LOG_FILE).write_text(log.getvalue())
        (work / batch_study.RESULT_FILE).write_text(json.dumps({"status": "ok"}))
        (work / batch_study.SETTINGS_FILE).write_text(json.dumps({"subject": {}}))
    with redirect_stdout(io.StringIO()):
        assert pdehead_batch.main(["depth-table", str(out), "--out", str(out / "table.csv")]) == 0
    return out


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def test_batch_depth_table_means_lie_within_the_t_table(batch_over_three_heads):
    out = batch_over_three_heads
    table = default_table()
    made = _rows(out / "table.csv")
    checked = 0
    for r in made:
        entry = table.entries.get(r["landmark"])
        if entry is None or entry.sd_mm is None:
            continue
        mean = float(r["mean_mm"])
        assert abs(mean - entry.mean_mm) <= 3 * entry.sd_mm, (r, entry)
        checked += 1
    assert checked >= 15                     # the table still covers most of the T-Table's landmarks
    ok_counts = {}
    for head in ("cthead", "ge", "phantom"):
        rows = _rows(out / head / "landmarks.csv")
        ok = [r for r in rows if r["flag"] == "ok"]
        ok_counts[head] = len(ok)
        for r in ok:                         # every ok depth: plausible on its own
            entry = table.entries.get(r["landmark"])
            if entry is not None and entry.sd_mm is not None:
                assert abs(float(r["depth_mm"]) - entry.mean_mm) <= 3 * entry.sd_mm, (head, r)
        log = (out / head / "log.txt").read_text()
        for line in (x for x in log.splitlines() if x.startswith("depth uncertain: ")):
            name = line.split(": ")[1]
            assert next(r["flag"] for r in rows if r["landmark"] == name) == "uncertain", line
    assert ok_counts["cthead"] >= 15 and ok_counts["phantom"] >= 20, ok_counts
    logs = "".join((out / h / "log.txt").read_text() for h in ("cthead", "ge", "phantom"))
    # each new rule demotes something on these heads, with its measured reason
    assert "more than 1.5 x the nearest skin's" in logs
    assert "outside the table's mean +- 3 SD" in logs
    assert "of the scan's edge" in (out / "ge" / "log.txt").read_text()
