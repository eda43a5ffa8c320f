"""The VDB volume and its eq. 24 material (operators/volume/volume.py, vdb_files.py, vdb_grids.py, volume_material.py;
its windowing and grids: tests/core/test_ct_volume.py).

- the .vdb grids and their index -> world transform (numpy [z, y, x] vs OpenVDB (x, y, z)),
- the Volume object of the phantom's w-field lining up with the PDE surface,
- the shader: node types and links, and an evaluation of the node group's maths (eq. 24,
  zero outside the solid, never negative),
- relative paths, save / reopen, and the message for a missing .vdb.
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import blender_inspect  # tests/blender/blender_inspect.py
import vdb_read  # tests/blender/vdb_read.py
from pdehead_addon import OUTSIDE_W, defaults as D
from pdehead_addon.core.ct_volume import HEAD_MARGIN_MM, head_mask_on_grid

MM = 0.001


@pytest.fixture(scope="module")
def phantom_wfield(phantom_head, phantom):
    return phantom_head.w_field(3.0, ct=phantom.ct)


# ----------------------------------------------------------------------------- the .vdb file
def _oblique_wfield():
    """A small asymmetric grid with oblique axes and anisotropic spacing: every axis mix-up shows."""
    nz, ny, nx = 6, 7, 9
    a = math.radians(18.5)
    direction = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    w = (0.01 * i + 0.1 * j + 0.05 * k).astype(np.float32) / 1.5   # distinct per axis, < 1
    w[:, :, 0] = 2.0                                               # outside (OUTSIDE_W)
    intensity = (100.0 * i + 10.0 * j + k).astype(np.float32)
    intensity[w > 1] = 0.0
    return SimpleNamespace(w=w, intensity=intensity, spacing=(4.0, 1.08, 0.9), origin=np.array([-120.0, 30.0, 55.0]),
                           direction=direction)


def _needs_openvdb(ext):
    """Skip the rest of a test that reads .vdb files back, on Blenders without OpenVDB bindings (bpy 4.2)."""
    import bpy
    if not vdb_read.has_openvdb():
        pytest.skip(f"bpy {bpy.app.version_string} has no OpenVDB Python bindings to read .vdb files back; "
                    "its volumes come from operators/volume/vdb_writer.py (tests/blender/test_vdb_writer.py)")


def test_write_vdb_grids_values_and_transform(ext, tmp_path):
    _needs_openvdb(ext)
    from pdehead_addon import CTVolume
    wf = _oblique_wfield()
    ct = CTVolume(wf.intensity + 5.0, wf.spacing, wf.origin, wf.direction)  # the full CT on the same grid
    window = (0.0, 900.0)
    origin_m = np.array([0.01, -0.02, 0.03])
    path = ext.volume.vdb_grids.write_vdb(wf, tmp_path / "sub" / "t.vdb", window, ct=ct, origin_m=origin_m)
    assert path.is_file()
    info = vdb_read.read_vdb_grids(path)
    assert set(info) == {"w", "intensity", "ct"}
    assert info["w"]["background"] == OUTSIDE_W == 2.0
    assert info["intensity"]["background"] == 0.0
    nz, ny, nx = wf.w.shape
    # w: voxels of column i = 0 are outside -> inactive; box spans i 1..nx-1, all j, all k
    assert info["w"]["active_box"] == ((1, 0, 0), (nx - 1, ny - 1, nz - 1))
    lo, hi = info["w"]["min_max"]
    assert 0.0 <= lo and hi <= 1.0
    for name in ("intensity", "ct"):
        lo, hi = info[name]["min_max"]
        assert 0.0 <= lo and hi <= 1.0  # windowed, never negative
    # transform: index axes = spacing x direction in metres, origin relative to the object origin
    expected = ext.coords.grid_affine_world(wf.spacing, wf.origin, wf.direction)
    np.testing.assert_allclose(info["w"]["axes"], expected[:3, :3].T, atol=1e-9)
    np.testing.assert_allclose(info["w"]["origin"] + origin_m, wf.origin * MM, atol=1e-9)
    # known voxels: OpenVDB (i, j, k) holds numpy [k, j, i]
    for k, j, i in [(0, 0, 1), (5, 6, 8), (2, 3, 4), (4, 1, 7), (3, 5, 0)]:
        assert vdb_read.vdb_value(path, "w", (i, j, k)) == pytest.approx(float(wf.w[k, j, i]), abs=1e-6)
        inten = vdb_read.vdb_value(path, "intensity", (i, j, k))
        ctv = vdb_read.vdb_value(path, "ct", (i, j, k))
        if wf.w[k, j, i] <= 1:  # display grids are stored as half floats: 1e-3 is their precision in [0, 1]
            assert inten == pytest.approx(min(1.0, wf.intensity[k, j, i] / 900.0), abs=1e-3)
        else:
            assert inten == 0.0
        assert ctv == pytest.approx(min(1.0, (wf.intensity[k, j, i] + 5.0) / 900.0), abs=1e-3)
        world = np.array(ext.coords.grid_affine_world(wf.spacing, wf.origin, wf.direction) @ [i, j, k, 1])[:3]
        np.testing.assert_allclose(world, ct.index_to_patient([k, j, i]) * MM, atol=1e-12)


def test_ct_grid_covers_the_whole_ct_box_on_its_own_grid(ext, tmp_path):
    _needs_openvdb(ext)
    """A CT on another grid keeps its own grid (whole box, own transform), decimated to the w-field voxel."""
    from pdehead_addon import CTVolume
    wf = _oblique_wfield()                                               # voxels 4.0 x 1.08 x 0.9 mm
    fine = np.fromfunction(lambda k, j, i: 3.0 * i + 2.0 * j + 1.0 * k, (30, 40, 50), dtype=np.float32)
    ct = CTVolume(fine, (0.5, 0.3, 0.3), origin=(-125.0, 25.0, 50.0))   # finer: decimated by (2, 3, 3)
    origin_m = np.array([0.002, 0.004, -0.001])
    path = ext.volume.vdb_grids.write_vdb(wf, tmp_path / "r.vdb", (0.0, 400.0), ct=ct, origin_m=origin_m)
    info = vdb_read.read_vdb_grids(path)
    np.testing.assert_allclose(info["ct"]["axes"], np.diag([0.9, 0.9, 1.0]) * MM, atol=1e-12)
    # blocks of 2 slices average slices 2k-1, 2k: their centre is half a slice below slice 2k
    np.testing.assert_allclose(info["ct"]["origin"] + origin_m, (ct.origin + [0, 0, -0.25]) * MM, atol=1e-12)
    # the CT's own (decimated) grid: ceil(50/3) x ceil(40/3) x 30/2 voxels, kept only within
    # HEAD_MARGIN_MM of the solid (no air box outline, no scanner table in the intensity mode)
    mask = head_mask_on_grid(wf, (15, 14, 17), (1.0, 0.9, 0.9), ct.origin + [0, 0, -0.25], np.eye(3))
    assert 0.2 < mask.mean() < 0.95  # both kept and masked voxels: a real check
    kk, jj, ii = np.nonzero(mask)
    assert tuple(info["ct"]["active_box"][1]) == (ii.max(), jj.max(), kk.max())
    np.testing.assert_allclose(info["w"]["axes"], ext.coords.grid_affine_world(
        wf.spacing, wf.origin, wf.direction)[:3, :3].T, atol=1e-12)  # the w grid keeps its own transform
    kept, masked = np.argwhere(mask), np.argwhere(~mask)
    for k, j, i in [*kept[::max(1, len(kept) // 5)], *masked[::max(1, len(masked) // 4)], (1, 1, 1), (12, 2, 10)]:
        # block mean of a linear ramp = the ramp at the block centre (x: 3i-1 .. 3i+1, z: 2k-1 .. 2k)
        expected = (3.0 * 3 * i + 2.0 * 3 * j + 1.0 * (2 * k - 0.5)) / 400.0 if mask[k, j, i] else 0.0
        assert vdb_read.vdb_value(path, "ct", (int(i), int(j), int(k))) == pytest.approx(min(1.0, expected), abs=2e-3)


# ----------------------------------------------------------------------------- the Volume object
def test_volume_object_lines_up_with_the_surface(ext, phantom, phantom_head, phantom_wfield, tmp_path):
    import bpy
    coll = ext.scene.objects.study_collection("Phantom")
    surface = ext.scene.objects.build_surface(phantom_head, coll, nu=60, nv=90)
    vol = ext.volume.volume.build_volume(phantom_wfield, coll, tmp_path / "Phantom.vdb", ct=phantom.ct)
    assert vol.type == "VOLUME" and vol.name in coll.objects
    assert ext.volume.volume.check_volume(vol) is None
    grids = vol.data.grids
    assert grids.load() and {g.name for g in grids} >= {"w", "intensity", "ct"}
    np.testing.assert_allclose(np.array(vol.location), np.array(surface.location))  # one study origin

    wf = phantom_wfield
    inside = wf.w <= 1.0
    assert 0.05 < inside.mean() < 0.9
    # where Blender puts the w grid's voxels: object matrix x the grid's own transform
    to_world = np.array(vol.matrix_world) @ np.array(grids["w"].matrix_object)
    expected = ext.coords.grid_affine_world(wf.spacing, wf.origin, wf.direction)
    np.testing.assert_allclose(to_world, expected, atol=1e-7)
    _needs_openvdb(ext)
    # the active w voxels (the solid) cover the same box as the surface mesh, to a voxel
    info = vdb_read.read_vdb_grids(bpy.path.abspath(vol.data.filepath))
    (i0, j0, k0), (i1, j1, k1) = info["w"]["active_box"]
    box = np.array([[i, j, k, 1.0] for i in (i0, i1) for j in (j0, j1) for k in (k0, k1)]) @ to_world.T
    surf_world = blender_inspect.mesh_world_vertices(surface)
    voxel = max(wf.spacing) * MM
    np.testing.assert_allclose(box[:, :3].min(0), surf_world.min(0), atol=1.5 * voxel)
    np.testing.assert_allclose(box[:, :3].max(0), surf_world.max(0), atol=1.5 * voxel)
    # a voxel deep inside: the file holds the engine's w at the world position of that voxel
    k, j, i = np.argwhere(inside)[len(np.argwhere(inside)) // 2]
    assert vdb_read.vdb_value(bpy.path.abspath(vol.data.filepath), "w", (i, j, k)) == pytest.approx(
        float(wf.w[k, j, i]), abs=1e-6)
    # render framing: the solid's box in eq. 24 mode; in intensity-alpha mode the CT kept around the head
    # (HEAD_MARGIN_MM around the solid: no air box outline, no table)
    lo, hi = ext.scene.render.world_bounds([vol])
    np.testing.assert_allclose(lo, surf_world.min(0), atol=2 * voxel)  # voxel box + half a voxel
    np.testing.assert_allclose(hi, surf_world.max(0), atol=2 * voxel)
    ext.volume.material.set_volume_settings(vol, alpha_mode="INTENSITY")
    lo, hi = ext.scene.render.world_bounds([vol])
    ct_lo, ct_hi = (np.asarray(b) * MM for b in phantom.ct.bounds())
    margin = HEAD_MARGIN_MM * MM
    assert np.all(lo <= surf_world.min(0) + voxel) and np.all(hi >= surf_world.max(0) - voxel)
    leaf = 8 * 4.0 * MM  # Blender's volume bounds follow OpenVDB leaf nodes: 8 voxels of the ~4 mm ct grid
    assert np.all(lo >= ct_lo - leaf) and np.all(hi <= ct_hi + leaf)
    assert np.all(lo >= surf_world.min(0) - margin - leaf) and np.all(hi <= surf_world.max(0) + margin + leaf)
    assert lo[0] > ct_lo[0] + 0.01 and hi[0] < ct_hi[0] - 0.01  # the air at the CT box's sides is not drawn
    assert np.all(lo <= surf_world.min(0)) and np.all(hi >= surf_world.max(0))


# ----------------------------------------------------------------------------- the material
def _link_into(tree, node, socket_name):
    links = [lk for lk in tree.links if lk.to_node == node and socket_name in (lk.to_socket.name,
                                                                              lk.to_socket.identifier)]
    assert len(links) == 1, f"{node.name}.{socket_name} is not linked"
    return links[0].from_node, links[0].from_socket


def test_volume_material_node_tree(ext, tmp_path):
    import bpy
    coll = ext.scene.objects.study_collection("S")
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, tmp_path / "S.vdb")
    mat = vol.material_slots[0].material
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    pv, _ = _link_into(tree, out, "Volume")
    assert pv.bl_idname == "ShaderNodeVolumePrincipled"
    assert not any(lk.to_node == out and lk.to_socket.name == "Surface" for lk in tree.links)
    # density and emission: the eq. 24 group's outputs x the colour ramp's alpha (the transfer function)
    ramp, _ = _link_into(tree, pv, "Color")
    assert ramp.bl_idname == "ShaderNodeValToRGB" and _link_into(tree, pv, "Emission Color")[0] == ramp
    for pv_input in ("Density", "Emission Strength"):
        mult, _ = _link_into(tree, pv, pv_input)
        assert (mult.bl_idname, mult.operation) == ("ShaderNodeMath", "MULTIPLY")
        group, socket = mult.inputs[0].links[0].from_node, mult.inputs[0].links[0].from_socket
        assert group.bl_idname == "ShaderNodeGroup" and group.node_tree.name == "PDE Head eq. 24"
        assert socket.name == pv_input
        assert mult.inputs[1].is_linked and mult.inputs[1].links[0].from_node == ramp
        assert mult.inputs[1].links[0].from_socket.name == "Alpha"
    assert _link_into(tree, ramp, "Fac")[0] == group  # identifier (named "Factor" from 5.0, "Fac" before)
    for socket_name, grid in (("W", "w"), ("Intensity", "intensity"), ("CT", "ct")):
        attr, out_socket = _link_into(tree, group, socket_name)
        assert attr.bl_idname == "ShaderNodeAttribute" and attr.attribute_name == grid
        assert attr.attribute_type == "GEOMETRY" and out_socket.identifier == "Fac"
    # inside the group: W -> clamp -> eq. 24 -> x inside -> mode mix -> clamp -> x density -> max(., 0) -> out
    g = group.node_tree
    items = {s.name: s for s in g.interface.items_tree if s.item_type == "SOCKET" and s.in_out == "INPUT"}
    assert items["Low Alpha"].default_value == pytest.approx(0.1)
    assert items["High Alpha"].default_value == pytest.approx(0.9)
    assert items["Density"].default_value > 0 and items["Intensity Alpha"].default_value == 0.0
    assert all(items[k].min_value >= 0.0 for k in ("Low Alpha", "High Alpha", "Density", "Emission"))
    assert items["Low Alpha"].max_value <= 1.0 and items["High Alpha"].max_value <= 1.0
    gout = next(n for n in g.nodes if n.bl_idname == "NodeGroupOutput")
    node, _ = _link_into(g, gout, "Density")
    assert (node.bl_idname, node.operation, node.inputs[1].default_value) == ("ShaderNodeMath", "MAXIMUM", 0.0)
    assert not node.inputs[1].is_linked
    chains = [c for c in _upstream_chains(g, gout.inputs["Density"]) if c[-1] == "input W"]
    assert sorted(chains) == sorted([
        ["MAXIMUM", "MULTIPLY", "ShaderNodeClamp", "ShaderNodeMix", "MULTIPLY", "MULTIPLY_ADD", "ShaderNodeClamp",
         "input W"],
        ["MAXIMUM", "MULTIPLY", "ShaderNodeClamp", "ShaderNodeMix", "MULTIPLY", "LESS_THAN", "input W"]])
    less = next(n for n in g.nodes if n.bl_idname == "ShaderNodeMath" and n.operation == "LESS_THAN")
    assert less.inputs[1].default_value == pytest.approx(1.0 + ext.volume.material.INSIDE_EPS)  # w > 1 (outside) -> 0
    assert bpy.data.node_groups["PDE Head eq. 24"].users >= 1


def _upstream_chains(tree, to_socket):
    """Every path of nodes from a group input up to `to_socket` (node labels, nearest first)."""
    for link in [lk for lk in tree.links if lk.to_socket == to_socket]:
        node = link.from_node
        if node.bl_idname == "NodeGroupInput":
            yield [f"input {link.from_socket.name}"]
            continue
        label = node.operation if node.bl_idname == "ShaderNodeMath" else node.bl_idname
        for socket in node.inputs:
            if socket.enabled:
                for chain in _upstream_chains(tree, socket):
                    yield [label] + chain


class _Evaluator:
    """Evaluates the float maths of a shader node group (Math, Clamp, Mix float) for given inputs."""

    def __init__(self, group, inputs: dict):
        self.g, self.inputs = group, inputs

    def socket_value(self, socket):
        links = [lk for lk in self.g.links if lk.to_socket == socket]
        if links:
            return self.output_value(links[0].from_node, links[0].from_socket)
        return float(socket.default_value)

    def output_value(self, node, socket):
        idn = node.bl_idname
        if idn == "NodeGroupInput":
            return float(self.inputs[socket.name])
        ins = [s for s in node.inputs if s.enabled]
        if idn == "ShaderNodeMath":
            a, b, c = (self.socket_value(s) for s in node.inputs)
            r = {"SUBTRACT": a - b, "MULTIPLY": a * b, "MULTIPLY_ADD": a * b + c, "LESS_THAN": float(a < b),
                 "MAXIMUM": max(a, b), "ADD": a + b}[node.operation]
            return min(max(r, 0.0), 1.0) if node.use_clamp else r
        if idn == "ShaderNodeClamp":
            assert node.clamp_type == "MINMAX"
            v, lo, hi = (self.socket_value(s) for s in ins)
            return min(max(v, lo), hi)
        if idn == "ShaderNodeMix":
            assert node.data_type == "FLOAT" and node.clamp_factor
            f, a, b = (self.socket_value(s) for s in ins)
            f = min(max(f, 0.0), 1.0)
            return (1 - f) * a + f * b
        raise AssertionError(f"unexpected node {idn}")

    def output(self, name):
        gout = next(n for n in self.g.nodes if n.bl_idname == "NodeGroupOutput")
        return self.socket_value(gout.inputs[name])


def test_eq24_density_computed_in_nodes_and_never_negative(ext):
    g = ext.volume.material.ensure_eq24_group()
    base = dict(Intensity=0.4, CT=0.7, Emission=0.5)
    for low, high in ((0.1, 0.9), (0.9, 0.1), (0.0, 1.0), (0.3, 0.3)):
        for w in np.linspace(-0.5, 3.0, 36):
            ev = _Evaluator(g, dict(base, W=w, **{"Low Alpha": low, "High Alpha": high, "Density": 20.0,
                                                  "Intensity Alpha": 0.0}))
            wc = min(max(w, 0.0), 1.0)
            alpha = (low - high) * wc + high if w <= 1.0 + ext.volume.material.INSIDE_EPS else 0.0   # eq. 24, 0 outside
            assert ev.output("Alpha") == pytest.approx(alpha, abs=1e-9)
            assert ev.output("Density") == pytest.approx(20.0 * alpha, abs=1e-9)
            assert ev.output("Emission Strength") == pytest.approx(10.0 * alpha, abs=1e-9)
            assert ev.output("Value") == pytest.approx(0.4)
    # the outside value written to the file gives exactly zero density
    ev = _Evaluator(g, dict(base, W=OUTSIDE_W, **{"Low Alpha": 0.1, "High Alpha": 0.9,
                                                                     "Density": 20.0, "Intensity Alpha": 0.0}))
    assert ev.output("Density") == 0.0
    # intensity-alpha baseline: alpha = CT everywhere (also outside the solid), colour from the CT
    for w in (0.2, 2.0):
        ev = _Evaluator(g, dict(base, W=w, **{"Low Alpha": 0.1, "High Alpha": 0.9, "Density": 20.0,
                                              "Intensity Alpha": 1.0}))
        assert ev.output("Density") == pytest.approx(14.0) and ev.output("Value") == pytest.approx(0.7)
    # hostile inputs (linked sockets can bypass the UI limits): density still >= 0
    for ct, dens, low, high in ((-3.0, 20.0, 0.1, 0.9), (0.5, -5.0, 0.1, 0.9), (0.5, 20.0, -1.0, -2.0)):
        for mode in (0.0, 1.0):
            ev = _Evaluator(g, dict(W=0.5, Intensity=-1.0, CT=ct, Emission=-2.0, **{
                "Low Alpha": low, "High Alpha": high, "Density": dens, "Intensity Alpha": mode}))
            assert ev.output("Density") >= 0.0 and ev.output("Emission Strength") >= 0.0
            assert 0.0 <= ev.output("Value") <= 1.0


def test_set_volume_settings(ext, tmp_path):
    coll = ext.scene.objects.study_collection("S")
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, tmp_path / "S.vdb", low_alpha=0.2, density=33.0)
    s = ext.volume.material.get_volume_settings(vol)
    assert s["low_alpha"] == pytest.approx(0.2) and s["high_alpha"] == pytest.approx(0.9)
    assert s["density"] == pytest.approx(33.0) and s["alpha_mode"] == "EQ24" and s["colour_preset"] == "grayscale"
    ext.volume.material.set_volume_settings(vol, high_alpha=0.7, colour_preset="skin", alpha_mode="INTENSITY")
    s = ext.volume.material.get_volume_settings(vol)
    assert s["low_alpha"] == pytest.approx(0.2) and s["high_alpha"] == pytest.approx(0.7)  # None kept low_alpha
    assert s["alpha_mode"] == "INTENSITY" and s["colour_preset"] == "skin"
    ramp = vol.material_slots[0].material.node_tree.nodes["Intensity colour"]
    stops = [(e.position, tuple(e.color)) for e in ramp.color_ramp.elements]
    assert len(stops) == len(ext.volume.material.COLOUR_PRESETS["skin"]) and stops[0][0] == 0.0 and stops[-1][0] == 1.0
    assert stops[2][1][0] > stops[2][1][1] > stops[2][1][2]  # skin tone: red > green > blue
    ext.volume.material.set_volume_settings(vol, colour_preset="grayscale", low_alpha=-3.0, density=-1.0)
    s = ext.volume.material.get_volume_settings(vol)
    assert s["low_alpha"] == 0.0 and s["density"] == 0.0  # clamped, never negative
    assert [tuple(e.color)[:3] for e in ramp.color_ramp.elements] == [(0, 0, 0), (1, 1, 1)]
    with pytest.raises(ValueError):
        ext.volume.material.set_volume_settings(vol, alpha_mode="TRANSFER")
    with pytest.raises(ValueError):
        ext.volume.material.set_volume_settings(vol, colour_preset="rainbow")


# ----------------------------------------------------------------------------- files
def test_vdb_folder_rules(ext, tmp_path):
    import tempfile
    blend = tmp_path / "a" / "study.blend"
    assert ext.volume.vdb_files.vdb_folder_for(str(blend), "/ignored") == (tmp_path / "a" / "pdehead_vdb").resolve()
    assert ext.volume.vdb_files.vdb_folder_for(None, str(tmp_path / "prefs")) == (tmp_path / "prefs").resolve()
    vdb_files = ext.volume.vdb_files
    assert vdb_files.vdb_folder_for(None, "") == __import__("pathlib").Path(tempfile.gettempdir()) / "pdehead_vdb"
    assert vdb_files.vdb_path_for("CT head: 1/2", str(blend)).parent == (tmp_path / "a" / "pdehead_vdb").resolve()
    assert "/" not in ext.volume.vdb_files.vdb_path_for("CT head: 1/2", str(blend)).name
    names = {ext.volume.vdb_files.vdb_path_for(n, str(blend)).name for n in ("CT head", "CT_head", "CT-head", "CThead")}
    assert len(names) == 4 and "study.CThead.vdb" in names  # distinct studies never share a file
    # named for their .blend: "a b.blend" and "a_b.blend" in one folder never own each other's files
    a, b = (ext.volume.vdb_files.vdb_path_for("S", str(tmp_path / "a" / f"{stem}.blend")) for stem in ("a b", "a_b"))
    assert a.name != b.name and b.name == "a_b.S.vdb" and a.name.count(".") == 2
    assert ext.volume.vdb_files.is_owned(b, str(tmp_path / "a" / "a_b.blend"))
    assert not ext.volume.vdb_files.is_owned(b, str(tmp_path / "a" / "a b.blend"))
    assert not ext.volume.vdb_files.is_owned(b, str(tmp_path / "a" / "a.blend"))  # "a_b." does not start "a."


def test_saved_file_reopens_with_its_volume_and_missing_vdb_is_reported(ext, tmp_path):
    import bpy
    blend = tmp_path / "project" / "study.blend"
    blend.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    coll = ext.scene.objects.study_collection("Study 1")
    vdb = ext.volume.vdb_files.vdb_path_for("Study 1", bpy.data.filepath, None)
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, vdb, name="Study 1 Volume", high_alpha=0.8)
    assert vol.data.filepath == f"//pdehead_vdb/{vdb.name}" and vdb.name.startswith("study.Study_1-")
    assert vdb.is_file() and vdb.parent == blend.parent / "pdehead_vdb"
    bpy.ops.wm.save_mainfile()

    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    vol = bpy.data.objects["Study 1 Volume"]
    assert ext.volume.volume.check_volume(vol) is None
    assert vol.data.grids.load()
    assert {"w", "intensity"} <= {g.name for g in vol.data.grids}
    assert ext.volume.material.get_volume_settings(vol)["high_alpha"] == pytest.approx(0.8)

    # the project folder moved without its pdehead_vdb folder: a clear message, no exception
    moved = tmp_path / "moved"
    moved.mkdir()
    shutil.copy(blend, moved / "study.blend")
    bpy.ops.wm.open_mainfile(filepath=str(moved / "study.blend"))
    message = ext.volume.volume.check_volume(bpy.data.objects["Study 1 Volume"])
    assert message is not None and "not found" in message and "pdehead_vdb" in message
    assert ext.volume.volume.check_volume(None) is not None


def test_volume_built_unsaved_follows_the_file_when_saved(ext, tmp_path):
    import bpy
    prefs_folder = tmp_path / "prefs"
    coll = ext.scene.objects.study_collection("Unsaved")
    vdb = ext.volume.vdb_files.vdb_path_for("Unsaved", None, str(prefs_folder))
    assert vdb.parent == prefs_folder.resolve()
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, vdb)
    assert vol.data.filepath == str(vdb)  # absolute while the file is unsaved
    assert ext.volume.vdb_files.relocate_vdb(vol) is None  # nowhere to go yet
    blend = tmp_path / "saved" / "s.blend"
    blend.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    # the save handler moved it beside the .blend (relative path) and removed the temporary file
    new = blend.parent / "pdehead_vdb" / "s.Unsaved.vdb"  # named for its .blend
    assert new.is_file() and not vdb.exists()
    assert vol.data.filepath == "//pdehead_vdb/s.Unsaved.vdb" and ext.volume.volume.check_volume(vol) is None
    assert ext.volume.vdb_files.relocate_vdb(vol) is None  # already there

    # relocate_vdb itself (also used by that handler): copies, never overwrites a different file
    other = tmp_path / "other"
    assert ext.volume.vdb_files.relocate_vdb(vol, folder=other) == other.resolve() / "s.Unsaved.vdb"
    assert Path(bpy.path.abspath(vol.data.filepath)).resolve() == other.resolve() / "s.Unsaved.vdb" and new.is_file()
    ext.volume.vdb_files.mark_written(other / "s.Unsaved.vdb")  # from another folder: only what this session wrote
    new.unlink()  # (the copy may be a hard link of it: replaced, not written into)
    new.write_bytes(b"a different file")
    moved = ext.volume.vdb_files.relocate_vdb(vol)
    assert moved == blend.parent / "pdehead_vdb" / "s.Unsaved-2.vdb" and moved.is_file()
    assert new.read_bytes() == b"a different file" and ext.volume.volume.check_volume(vol) is None


def test_rebuilt_volume_goes_to_a_new_file_and_the_old_one_is_removed_after_saving(ext, tmp_path):
    import bpy
    blend = tmp_path / "p" / "s.blend"
    blend.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    coll = ext.scene.objects.study_collection("S")
    path = ext.volume.vdb_files.vdb_path_for("S", bpy.data.filepath)
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, path)
    first = Path(bpy.path.abspath(vol.data.filepath))
    first_bytes = first.read_bytes()
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, path, obj=vol)  # same target: never overwritten
    second = Path(bpy.path.abspath(vol.data.filepath))
    assert second != first and second.name == "s.S-2.vdb" and first.read_bytes() == first_bytes
    bpy.ops.wm.save_mainfile()  # the saved file no longer needs the first one
    assert not first.exists() and second.is_file() and ext.volume.volume.check_volume(vol) is None


def test_transfer_function_presets_set_colour_and_opacity(ext, tmp_path):
    """Skin, bone and X-ray presets: the ramp's alpha multiplies the density (a transfer function)."""
    coll = ext.scene.objects.study_collection("TF")
    vol = ext.volume.volume.build_volume(_oblique_wfield(), coll, tmp_path / "tf.vdb")
    ramp = vol.material_slots[0].material.node_tree.nodes["Intensity colour"].color_ramp
    assert {"grayscale", "skin", "bone", "xray"} <= set(ext.volume.material.COLOUR_PRESETS)
    ext.volume.material.set_volume_settings(vol, colour_preset="bone")
    assert ramp.evaluate(0.3)[3] == pytest.approx(0.0) and ramp.evaluate(0.95)[3] > 0.8  # soft tissue hidden
    ext.volume.material.set_volume_settings(vol, colour_preset="xray")
    air, mid, dense = (ramp.evaluate(x) for x in (0.02, 0.5, 1.0))
    assert air[3] == pytest.approx(0.0) and 0.2 < mid[3] < dense[3] and abs(mid[0] - mid[2]) < 1e-6  # grey
    ext.volume.material.set_volume_settings(vol, colour_preset="skin")
    tissue = ramp.evaluate(0.3)
    assert tissue[3] == pytest.approx(1.0) and tissue[0] > tissue[2] + 0.1 and ramp.evaluate(0.03)[3] < 0.05
    ext.volume.material.set_volume_settings(vol, colour_preset="grayscale")
    assert all(ramp.evaluate(x)[3] == pytest.approx(1.0) for x in (0.0, 0.5, 1.0))  # eq. 24 alone


def test_auto_voxel_size_follows_the_ct_spacing_within_the_budgets(ext, phantom, phantom_head):
    from pdehead_addon import CTVolume
    pts = phantom_head.surface(32, 64).vertices
    box = (pts.min(axis=0), pts.max(axis=0))
    size = ext.volume.vdb_grids.auto_voxel_size(phantom.ct, phantom_head)
    assert size >= min(phantom.ct.spacing) - 1e-9
    nbytes, voxels = ext.volume.vdb_grids.estimate_vdb(phantom.ct, box, size)
    assert nbytes <= D.MAX_VDB_BYTES.default and voxels <= D.MAX_WFIELD_VOXELS.default
    # a much finer CT over the same box is coarsened only as far as the budgets need
    fine = CTVolume(np.zeros((4, 4, 4), np.float32), (0.3, 0.3, 0.3), origin=phantom.ct.origin)
    fine.data = np.zeros((600, 700, 700), np.float32)[:1, :1, :1]  # spacing matters, not the data
    small = ext.volume.vdb_grids.auto_voxel_size(fine, phantom_head, max_voxels=1e6)
    estimate = ext.volume.vdb_grids.estimate_vdb
    assert estimate(fine, box, small)[1] <= 1e6 < estimate(fine, box, small / 1.06)[1]
    coarse = CTVolume(np.zeros((4, 4, 4), np.float32), (3.0, 3.0, 3.0))
    assert ext.volume.vdb_grids.auto_voxel_size(coarse, phantom_head) == pytest.approx(3.0)  # a 3 mm CT keeps 3 mm


def test_cutaway_angles_are_degrees_in_the_ui(pdehead_ext):
    import bpy
    rna = bpy.types.Object.bl_rna.properties["pdehead"].fixed_type.properties["v_range"]  # the settings Empty
    assert rna.unit == "ROTATION" and rna.soft_min == 0.0 and rna.soft_max == pytest.approx(2 * math.pi)
    op = bpy.ops.pdehead.build_solid.get_rna_type().properties["v_range"]
    assert op.unit == "ROTATION"
