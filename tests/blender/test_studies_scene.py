"""Issue 19: an import that builds the head ends framed; studies and the scene (camera, .vdb files)."""
from __future__ import annotations

import sys

import pytest


@pytest.fixture(scope="module")
def phantom_dicom(tmp_path_factory):
    """The phantom as an untilted DICOM series (what a user drops in or imports)."""
    from pdehead_addon import make_phantom
    from pdehead_addon.validation.dicom_export import write_phantom_series
    folder = tmp_path_factory.mktemp("phantom-dicom") / "series"
    write_phantom_series(make_phantom(), folder, gantry_tilt=0.0, rows=128, columns=128, pixel_spacing=(2.0, 2.0),
                         noise=False)
    return folder


def _on_screen(camera, scene, point) -> tuple[float, float]:
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector
    co = world_to_camera_view(scene, camera, Vector(point))
    return float(co.x), float(co.y)


def test_import_with_build_the_head_ends_framed(ext, phantom_dicom):
    """File > Import > CT Head with "Build the Head" on Blender's startup file: the study camera is the
    scene camera and looks at the head, the startup cube is hidden, the surface is what F12 shows."""
    import bpy
    bpy.ops.wm.read_homefile(use_factory_startup=True)
    scene = bpy.context.scene
    cube, default_camera = scene.objects["Cube"], scene.camera
    assert default_camera is not None and not cube.hide_render
    assert bpy.ops.pdehead.import_ct(directory=str(phantom_dicom), run_pipeline=True) == {'FINISHED'}
    coll = scene.pdehead.active_study
    s = ext.state.settings(coll)
    assert s.surface_object and s.solid_object
    camera = ext.scene.scene.study_object(coll, ext.scene.scene.CAMERA_KIND)
    assert camera is not None and scene.camera == camera and camera != default_camera
    assert cube.hide_render and not cube.visible_get()
    assert not s.surface_object.hide_render and s.solid_object.hide_render and s.curves_object.hide_render
    lo, hi = ext.scene.render.world_bounds([s.surface_object])
    x, y = _on_screen(camera, scene, 0.5 * (lo + hi))
    assert x == pytest.approx(0.5, abs=0.02) and y == pytest.approx(0.5, abs=0.02)
    corners = [_on_screen(camera, scene, (a, b, c)) for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
               for c in (lo[2], hi[2])]
    assert all(0.0 <= u <= 1.0 and 0.0 <= v <= 1.0 for u, v in corners)  # the whole head in the frame


def _pipeline(bpy, **kw):
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3, **kw) == {'FINISHED'}
    return bpy.context.scene.pdehead.active_study


def test_remove_study_falls_back_to_another_studys_camera(ext):
    import bpy
    first = _pipeline(bpy, build_volume=False)
    first_name = first.name
    second = _pipeline(bpy, build_volume=False)
    scene = bpy.context.scene
    assert scene.camera == ext.scene.scene.study_object(second, ext.scene.scene.CAMERA_KIND)
    assert bpy.ops.pdehead.remove_study() == {'FINISHED'}  # the active study: the second
    first = bpy.data.collections[first_name]
    assert scene.pdehead.active_study == first
    assert scene.camera is not None and scene.camera == ext.scene.scene.study_object(first, ext.scene.scene.CAMERA_KIND)


def test_save_removes_the_vdb_of_a_study_deleted_in_the_outliner(ext, tmp_path):
    """Only this file's own .vdb that no volume uses any more goes; the other study's, a foreign .vdb
    and other files in the folder stay."""
    import bpy
    blend = tmp_path / "two.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    kept = _pipeline(bpy, voxel_size=8.0)
    gone = _pipeline(bpy, voxel_size=8.0)
    bpy.ops.wm.save_mainfile()
    folder = tmp_path / ext.volume.vdb_files.VDB_FOLDER_NAME
    kept_vdb = folder / bpy.path.basename(ext.state.settings(kept).volume_object.data.filepath)
    gone_vdb = folder / bpy.path.basename(ext.state.settings(gone).volume_object.data.filepath)
    assert kept_vdb.is_file() and gone_vdb.is_file() and kept_vdb != gone_vdb
    foreign = folder / "someone_else.vdb"
    foreign.write_bytes(gone_vdb.read_bytes())
    notes = folder / "notes.txt"
    notes.write_text("not ours")

    # Outliner > Delete Hierarchy on the second study: its objects and collection go, nothing else runs
    for obj in list(gone.all_objects):
        bpy.data.objects.remove(obj)
    bpy.data.collections.remove(gone)
    bpy.ops.wm.save_mainfile()
    assert not gone_vdb.exists()
    assert kept_vdb.is_file() and foreign.is_file() and notes.read_text() == "not ours"
    # reopened: the kept study's volume still reads its grids
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    volumes = [o for o in bpy.data.objects if o.type == 'VOLUME']
    assert len(volumes) == 1 and bpy.path.basename(volumes[0].data.filepath) == kept_vdb.name
    volumes[0].data.grids.load()
    assert "w" in {g.name for g in volumes[0].data.grids}
    assert sorted(p.name for p in folder.glob("*.vdb")) == sorted([kept_vdb.name, foreign.name])


def test_drag_and_drop_opens_the_import_with_the_file(ext, pdehead_ext, phantom_dicom, pytestconfig):
    """Blender's FileHandler for the 3D View: a dropped .dcm opens the import on its series folder, a
    .nii.gz on the file alone, a .raw / .tif on its stack's folder; the dialog's values import the CT."""
    from types import SimpleNamespace

    import bpy
    handler = bpy.types.FileHandler.bl_rna_get_subclass_py("PDEHEAD_FH_import_ct")
    assert handler is not None and handler.bl_import_operator == "pdehead.import_ct"
    assert {".dcm", ".nii", ".nii.gz", ".tif", ".tiff", ".raw"} <= set(handler.bl_file_extensions.split(";"))
    assert handler.poll_drop(SimpleNamespace(area=SimpleNamespace(type='VIEW_3D')))
    assert not handler.poll_drop(SimpleNamespace(area=SimpleNamespace(type='NODE_EDITOR')))

    options = sys.modules[f"{pdehead_ext.__name__}.operators.ui.import_options"].dropped_file_options
    dcm = sorted(p.name for p in phantom_dicom.iterdir())[3]
    got = options(str(phantom_dicom), [dcm])
    assert got["format"] == "DICOM" and not got["single_file"] and got["directory"] == str(phantom_dicom)
    nii = options("/data/mri", ["ch2.nii.gz"])
    assert nii["single_file"] and nii["filepath"] == "/data/mri/ch2.nii.gz"
    assert options("/d", ["slice_001.raw"])["format"] == "RAW" and options("/d", ["a.TIFF"])["format"] == "IMAGES"
    assert options("/d", ["notes.txt"]) == {}

    # the dialog's OK: what Blender runs with the dropped file's values
    assert bpy.ops.pdehead.import_ct(files=[{"name": dcm}], **got) == {'FINISHED'}
    s = ext.state.settings(bpy.context.scene.pdehead.active_study)
    assert s.source_kind == 'FILES' and s.source == str(phantom_dicom)
    assert tuple(s.dimensions)[:2] == (128, 128) and s.dimensions[2] > 20  # the whole series, not one slice
