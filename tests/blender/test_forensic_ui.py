"""Forensic toolkit in Blender and in the CLI (issue 12): skull, depth map, landmarks, pegs, Frankfurt, export."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from file_readers import read_stl
from pdehead_addon.io.phantom import GEOMETRY
from test_cli import run_cli


def _check_export(folder, n_skin_vertices=None, handles=True):
    skin, skull = read_stl(folder / "skin.stl"), read_stl(folder / "skull.stl")
    envelope = read_stl(folder / "skull_envelope.stl")
    assert skin.is_watertight() and skull.is_watertight() and envelope.is_watertight()
    assert len(skull.triangles) <= 500_000
    # the bone skull is open where bone is (orbits, foramina, arches): handles, unlike the PDE envelope
    euler = [len(m.vertices) - len(m.edges()) + len(m.triangles) for m in (skull, envelope)]
    assert euler[1] == 2                                                  # the envelope: one closed sphere
    if handles:                                                           # real skulls: many (CThead -490)
        assert euler[0] <= -20
    prov = json.loads((folder / "provenance.json").read_text())
    assert prov["software"].startswith("PDE Head ") and "bone_level" in prov and prov["table"].startswith("T-Table")
    assert open(folder / "skull.stl", "rb").read(80).decode("ascii").startswith("skull (patient LPS, mm); PDE Head")
    lm = (folder / "landmarks.csv").read_text().splitlines()
    assert lm[0].startswith("# software: PDE Head") and any(ln.startswith("# bone_level: ") for ln in lm)
    assert "# depth: bone level to skin level in the CT along the bone's exposed normal" in lm   # as the batch
    assert [ln for ln in lm if not ln.startswith("#")][0] == \
        "landmark,x_mm,y_mm,z_mm,depth_mm,table_mm,table_name,sd_mm,flag"
    rows = [r for r in csv.reader(open(folder / "tissue_depth.csv")) if not r[0].startswith("#")]
    assert rows[0][:4] == ["x_mm", "y_mm", "z_mm", "depth_mm"]
    body = rows[1:]
    if n_skin_vertices is not None:
        assert len(body) == n_skin_vertices
    pts = np.array([[float(v) for v in r[:3]] for r in body])
    depth = np.array([float(r[3]) if r[3] else np.nan for r in body])
    assert all((r[3] == "") == (r[5] != "measured") for r in body)        # empty exactly where no bone
    return skin, skull, pts, depth


@pytest.mark.engine_cli
def test_cli_phantom_skull_export(tmp_path):
    out = tmp_path / "print"
    result = run_cli("--phantom", "--no-volume", "--nu", 60, "--nv", 120, "--skull", "--export", out, tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "  skull     bone level" in result.stdout and "  depth     " in result.stdout
    skin, skull, pts, depth = _check_export(out, handles=False)
    # in mm: the phantom's skull is 136 mm wide (outer ellipsoid semi-axis 68), its skin 150 mm without ears
    (cx, cy, cz), (a, b, c) = GEOMETRY["skull_outer"]
    width = np.ptp(skull.vertices[:, 0])
    assert abs(width - 2 * a) < 3.0
    assert 140 < np.ptp(skin.vertices[:, 0]) < 170
    vault = pts[:, 2] > 45
    assert np.isfinite(depth[vault]).mean() > 0.95
    assert abs(np.nanmedian(depth[vault]) - 6.0) < 0.5


def test_cli_export_needs_skull(tmp_path):
    result = run_cli("--phantom", "--export", tmp_path / "x", tmp_path=tmp_path)
    assert result.returncode == 2 and "--export needs --skull" in result.stderr
    assert not (tmp_path / "x").exists()


@pytest.mark.engine_cli
def test_cli_cthead_skull_export(tmp_path, pytestconfig):
    from datasets import shared_data
    folder = shared_data("cthead_stanford", "raw16")
    out = tmp_path / "print"
    result = run_cli(folder, "--raw-shape", 256, 256, "--dtype", ">i2", "--spacing", 2, 1, 1, "--first-slice",
                     "superior", "--no-volume", "--nu", 60, "--nv", 120, "--skull", "--export", out,
                     tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    skin, skull, pts, depth = _check_export(out)
    assert "mandible" not in result.stdout                   # present and articulated: no warning
    assert 120 < np.ptp(skull.vertices[:, 0]) < 170          # a skull in mm (CThead spacing 1 x 1 x 2 mm)
    assert 0.5 < np.isfinite(depth).mean() < 0.95            # neck, ears and orbit rays have no value
    assert 3.0 < np.nanmedian(depth) < 10.0


@pytest.mark.engine_cli
def test_cli_ge_skull_export(tmp_path):
    """The GE series stops at the maxilla: a skull without mandible, a tilted, unevenly spaced scan."""
    from datasets import shared_data
    out = tmp_path / "print"
    result = run_cli(shared_data("ct_head_ge_tilt_dicom", "dicom"), "--no-volume", "--nu", 60, "--nv", 120,
                     "--skull", "--export", out, "--export-format", "stl", tmp_path=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    skin, skull, pts, depth = _check_export(out)
    # the missing-mandible path
    assert "no mandible found: the face has no jaw or chin and ends along the scan's cut" in result.stdout
    # landmarks Find Landmarks did not find keep a row in landmarks.csv, flagged, without coordinates (measured 28 of
    # 50, every mandible landmark among them)
    lines = [ln for ln in (out / "landmarks.csv").read_text().splitlines() if not ln.startswith("#")]
    missing = [r for r in csv.DictReader(lines) if r["flag"] == "not_found"]
    assert len(missing) >= 20 and all(r["x_mm"] == "" and r["depth_mm"] == "" for r in missing)
    assert {"Pogonion", "Menton", "Gonion L", "Gonion R"} <= {r["landmark"] for r in missing}
    assert 120 < np.ptp(skull.vertices[:, 0]) < 170 and np.ptp(skull.vertices[:, 0]) < np.ptp(skin.vertices[:, 0])
    top = pts[:, 2] > pts[:, 2].max() - 60                  # the vault: measured on nine tenths of it
    # against the bone skull from the binary bone mask (issue 22): 0.77 measured with the 4 mm tilted slices
    # meshed as they are (terraces one slice high and slits in the thin vault); 0.91 (engine, t = 8, 120 x 240)
    # since skull_mesh interpolates 3 slices between each two (shape-based) before marching cubes
    assert np.isfinite(depth[top]).mean() > 0.85 and 3.0 < np.nanmedian(depth[top]) < 10.0


def test_forensic_operators_on_the_phantom(pdehead_ext, tmp_path):
    import bpy
    from mathutils import Vector

    forensic = __import__(f"{pdehead_ext.__name__}.operators.forensic.study", fromlist=["x"])
    skull = __import__(f"{pdehead_ext.__name__}.operators.forensic.skull", fromlist=["x"])
    export = __import__(f"{pdehead_ext.__name__}.operators.forensic.export", fromlist=["x"])
    study_entity = __import__(f"{pdehead_ext.__name__}.operators.study.entity", fromlist=["x"])
    bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=40, nv=80, nw=4, voxel_size=6.0)
    coll = bpy.context.scene.pdehead.active_study
    fs = forensic.ForensicStudy.of(study_entity.Study.of(coll))
    assert fs is forensic.ForensicStudy.of(study_entity.Study.of(coll))      # one object per study
    assert bpy.ops.pdehead.build_skull() == {'FINISHED'}
    skull_obj = coll["pdehead_skull_object"]
    bone_obj = coll["pdehead_bone_object"]
    assert len(skull_obj.data.vertices) == len(fs.skull.skull_engine_mesh("PDE").vertices) > 2000
    assert len(bone_obj.data.polygons) > 10000

    assert bpy.ops.pdehead.tissue_depth(max_depth=35.0) == {'FINISHED'}
    assert (fs.props.target, fs.props.max_depth) == ('BONE', 35.0)          # the study's forensic settings
    surf = coll.pdehead.surface_object
    depth = np.empty(len(surf.data.vertices), np.float32)
    surf.data.attributes["tissue_depth"].data.foreach_get("value", depth)
    co = np.empty(len(surf.data.vertices) * 3, np.float32)
    surf.data.vertices.foreach_get("co", co)
    world = co.reshape(-1, 3) + np.array(surf.matrix_world.translation)
    vault = world[:, 2] > 0.045
    assert np.median(depth[vault]) == pytest.approx(6.0, abs=0.5)
    assert (depth == -1).sum() > 0                                       # no value below the skull
    stats = json.loads(coll["pdehead_depth_stats"])
    assert stats == fs.skull.depth_stats() and stats["max_depth_mm"] == 35.0
    assert stats["measured"] == int((depth >= 0).sum())
    assert surf.data.materials[0].name == skull.DEPTH_MATERIAL

    # landmarks snapped to the skull, pegs from a depth table, Frankfurt, mirror
    g_c, g_r = np.array(GEOMETRY["skull_outer"][0]), np.array(GEOMETRY["skull_outer"][1])
    points = {"Porion L": [g_r[0] + 4, 10, -5], "Porion R": [-g_r[0] - 4, 10, -5],
              "Orbitale L": [30, -70, 5], "Orbitale R": [-30, -70, 5], "Vertex": [0, 8, 100]}
    for name, p in points.items():
        r = bpy.ops.pdehead.place_landmark(name=name, location=Vector(np.array(p) * 0.001), use_location=True)
        assert r == {'FINISHED'}
    lms = fs.landmarks()
    assert set(lms) == set(points)
    assert lms["Vertex"][2] == pytest.approx(g_c[2] + g_r[2], abs=1.0)
    table = tmp_path / "table.csv"
    table.write_text("# test values, not a published table\nlandmark,depth_mm\nVertex,6\nPorion L,9\n")
    assert bpy.ops.pdehead.import_depth_table(filepath=str(table)) == {'FINISHED'}
    pegs = {o["pdehead_peg"]: o for o in coll.all_objects if "pdehead_peg" in o}
    assert set(pegs) == {"Vertex", "Porion L"}
    loaded = fs.outputs.depth_table()
    assert fs.props.depth_table_name == loaded.label and loaded.entries["Vertex"].mean_mm == 6.0

    def peg_world_z(peg):
        bpy.context.view_layer.update()                                  # the driver: depth_mm -> Z scale
        return np.array([peg.matrix_world @ v.co for v in peg.data.vertices])[:, 2]

    assert np.ptp(peg_world_z(pegs["Vertex"])) == pytest.approx(0.006, abs=0.0005)   # 6 mm upward from the vertex
    # the shipped T-Table 2023: the vertex peg shows the mean (5 mm) and is settable within mean +- 2 SD
    assert bpy.ops.pdehead.import_depth_table(default_table=True) == {'FINISHED'}
    pegs = {o["pdehead_peg"]: o for o in coll.all_objects if "pdehead_peg" in o}
    assert set(pegs) == {"Vertex"}                                       # porion and orbitale carry no depth
    peg = pegs["Vertex"]
    assert peg["depth_mm"] == 5.0 and peg["table_sd_mm"] == 1.5 and peg["table_name"].startswith("T-Table 2023")
    ui = peg.id_properties_ui("depth_mm").as_dict()
    assert (ui["min"], ui["max"]) == (2.0, 8.0)
    assert np.ptp(peg_world_z(peg)) == pytest.approx(0.005, abs=0.0005)
    assert export.set_peg_depth(peg, 7.5) == 7.5 and np.ptp(peg_world_z(peg)) == pytest.approx(0.0075, abs=0.0005)
    assert export.set_peg_depth(peg, 30.0) == 8.0                      # limited to mean + 2 SD
    base = np.array(peg.matrix_world.translation) / 0.001
    assert base == pytest.approx(lms["Vertex"], abs=1.0)                 # the peg stands on the landmark
    csv_path = tmp_path / "lm.csv"
    assert bpy.ops.pdehead.export_landmark_depths(filepath=str(csv_path)) == {'FINISHED'}
    body = [r for r in csv.reader(open(csv_path)) if not r[0].startswith("#")]
    assert len(body) == 1 + len(points) and body[0][-3:] == ["table_name", "sd_mm", "flag"]
    vertex = next(r for r in body if r[0] == "Vertex")
    assert vertex[5:] == ["5", peg["table_name"], "1.5", "ok"]
    # patient frame: the bone point of the depth, on the landmark's ray (the bone level's crossing in the CT)
    assert np.linalg.norm(np.array([float(c) for c in vertex[1:4]]) - lms["Vertex"]) < 1.0
    # the depth is measured as the batch measures it: on the CT's intensities along the bone's exposed normal
    # (depth_on_ct.measure_landmark_depths), not from the bone mesh to the PDE skin; the phantom's vault: 6.0 mm
    from pdehead_addon.forensic.depth_on_ct import measure_landmark_depths
    from pdehead_addon.forensic.landmarks import landmark_depths
    header = [r[0] for r in csv.reader(open(csv_path)) if r[0].startswith("#")]
    assert "# depth: bone level to skin level in the CT along the bone's exposed normal" in header
    skull_mesh, skin_mesh = fs.skull.skull_engine_mesh("BONE"), fs.skull.skin_engine_mesh()
    head = fs.study.cache.seg
    on_ct = measure_landmark_depths(lms, skull_mesh, skin_mesh, fs.skull.skull_segmentation(), head_mask=head.mask)
    assert {m.method for m in on_ct.values()} == {"ct"}
    assert float(vertex[4]) == pytest.approx(on_ct["Vertex"].depth, abs=0.005)
    assert float(vertex[4]) == pytest.approx(6.0, abs=0.5)
    for r in body[1:]:   # every row: the CT's bone point and depth; the flag demoted where the profile says so
        m = on_ct[r[0]]
        assert [float(c) for c in r[1:4]] == pytest.approx(m.point, abs=1e-3)
        assert (r[4] == "" and not np.isfinite(m.depth)) or float(r[4]) == pytest.approx(m.depth, abs=0.005)
        assert m.trusted or r[-1] == "uncertain"
    # without CT intensities the same function falls back to the meshes, and says so
    on_mesh = measure_landmark_depths(lms, skull_mesh, skin_mesh, None)
    mesh_only = landmark_depths(lms, skull_mesh, skin_mesh)
    assert {m.method for m in on_mesh.values()} == {"mesh"}
    assert all(m.evidence.startswith("no CT intensities") for m in on_mesh.values())
    assert all(m.depth == mesh_only[n][1] or not np.isfinite(m.depth) for n, m in on_mesh.items())

    assert bpy.ops.pdehead.frankfurt() == {'FINISHED'}
    m = np.array(coll["pdehead_frankfurt"]).reshape(4, 4)
    po = np.array([m[:3, :3] @ (lms[n] * 0.001) + m[:3, 3] for n in ("Porion L", "Porion R", "Orbitale L",
                                                                       "Orbitale R")])
    normal = np.linalg.svd(po - po.mean(0))[2][2]
    assert abs(normal[2]) > np.cos(np.radians(0.01))                     # the Frankfurt plane is horizontal
    assert np.array(coll["pdehead_skull_object"].matrix_world)[:3, :3] == pytest.approx(m[:3, :3])
    assert fs.landmarks()["Vertex"] == pytest.approx(lms["Vertex"])   # patient mm kept
    bpy.context.view_layer.objects.active = skull_obj
    assert bpy.ops.pdehead.mirror() == {'FINISHED'}
    mirrored = bpy.data.objects[f"{skull_obj.name} Mirrored"]
    # the landmark pairs are symmetric about x = 0 (to the snapping), so is the phantom's skull
    a = np.array([mirrored.matrix_world @ v.co for v in mirrored.data.vertices])
    b = np.array([skull_obj.matrix_world @ v.co for v in skull_obj.data.vertices])
    assert np.allclose(np.sort(a[:, 0]), np.sort(-b[:, 0]), atol=0.002)
    assert a[:, 2].mean() == pytest.approx(b[:, 2].mean(), abs=0.001)
    # the skull's own symmetry plane, no landmarks needed: the phantom is symmetric about x = 0
    mirrored.name = "landmark mirror"
    assert bpy.ops.pdehead.mirror(plane='SKULL') == {'FINISHED'}
    by_skull = np.array(bpy.data.objects[f"{skull_obj.name} Mirrored"].matrix_world)
    by_landmarks = np.array(mirrored.matrix_world)
    assert np.linalg.det(by_skull[:3, :3]) == pytest.approx(-1.0)
    # same plane within ~0.6 deg / 3 mm: the landmarks snap to the bone skull (binary mask, 2 mm voxels: the
    # orbitales land 0.7 mm asymmetric) and the guessed orbitales onto the rims of the phantom's orbits (the
    # facial skeleton of issue 22), a little less symmetrically than onto the old vault
    assert by_skull[:3, :3] == pytest.approx(by_landmarks[:3, :3], abs=0.02)
    assert by_skull[:3, 3] == pytest.approx(by_landmarks[:3, 3], abs=0.003)
    assert bpy.ops.pdehead.frankfurt(reset=True) == {'FINISHED'}
    assert np.array(skull_obj.matrix_world)[:3, :3] == pytest.approx(np.eye(3))

    out = tmp_path / "export"
    assert bpy.ops.pdehead.export_print(directory=str(out), format='ply') == {'FINISHED'}
    assert sorted(p.name for p in out.iterdir()) == ["landmarks.csv", "provenance.json", "skin.ply", "skull.ply",
                                                     "skull_envelope.ply", "tissue_depth.csv"]

    blend = tmp_path / "forensic.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    coll = [c for c in bpy.data.collections if c.get("pdehead_skull_boundaries")][0]
    surf = coll.pdehead.surface_object
    assert "tissue_depth" in surf.data.attributes and coll["pdehead_skull_object"] is not None
    fs = forensic.ForensicStudy.of(study_entity.Study.of(coll))
    assert set(fs.landmarks()) == set(points)
    assert fs.props.format_version == 1 and fs.props.max_depth == 35.0          # the forensic settings saved
    table = fs.outputs.depth_table()
    assert table.label.startswith("T-Table 2023") and fs.props.depth_table_name == table.label
