"""A volume's .vdb belongs to the .blend that wrote it (operators/volume/vdb_files.py, operators/study/persistence.py).

- Save As into the same folder, then a rebuild or a removed study, then a save: the original .blend's
  .vdb stays and its volume still loads;
- a tampered record of the file's .vdb files deletes nothing but this file's own;
- a Volume whose stored path is not a .vdb in ``//pdehead_vdb/`` (``/etc/passwd``, a file elsewhere) is
  never copied nor read: one report naming the study, the rest of the file saved and working.
"""
from __future__ import annotations

import json
from pathlib import Path


def _study_with_volume(ext):
    """The phantom pipeline, small, with its volume (8 mm voxels): (study collection, Volume object)."""
    import bpy
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3, voxel_size=8.0) \
        == {'FINISHED'}
    coll = bpy.context.scene.pdehead.active_study
    return coll, coll.pdehead.volume_object


def _vdb_of(vol) -> Path:
    import bpy
    return Path(bpy.path.abspath(vol.data.filepath)).resolve()


def _loads(ext, blend: Path, volume_name: str) -> Path:
    """Open `blend`: its volume reads its grids; returns the volume's file."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    vol = bpy.data.objects[volume_name]
    assert ext.volume.volume.check_volume(vol) is None, ext.volume.volume.check_volume(vol)
    return _vdb_of(vol)


def test_save_as_in_the_same_folder_then_rebuild_or_remove_keeps_the_originals_volume(ext, tmp_path):
    import bpy
    orig, copy = tmp_path / "orig.blend", tmp_path / "copy.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(orig))
    coll, vol = _study_with_volume(ext)
    study, vname = coll.name, vol.name
    bpy.ops.wm.save_mainfile()
    orig_vdb = _vdb_of(vol)
    orig_bytes = orig_vdb.read_bytes()
    assert orig_vdb.name == f"orig.{study}.vdb" and ext.volume.vdb_files.is_owned(orig_vdb, str(orig))

    # Save As into the same folder: the copy gets its own file (a link or a copy), the original's is untouched
    bpy.ops.wm.save_as_mainfile(filepath=str(copy))
    copy_vdb = _vdb_of(bpy.data.objects[vname])
    assert copy_vdb.name == f"copy.{study}.vdb" and copy_vdb.parent == orig_vdb.parent
    assert copy_vdb.read_bytes() == orig_bytes

    # rebuild in the copy and save: the copy's replaced file goes, the original's stays
    assert bpy.ops.pdehead.build_volume(voxel_size=7.0) == {'FINISHED'}
    rebuilt = _vdb_of(bpy.data.objects[vname])
    assert rebuilt.name == f"copy.{study}-2.vdb"
    bpy.ops.wm.save_mainfile()
    assert not copy_vdb.exists() and rebuilt.is_file()
    assert orig_vdb.is_file() and orig_vdb.read_bytes() == orig_bytes

    # remove the study in the copy and save: only the copy's file goes
    ext.study.entity.Study.of(coll).remove()
    bpy.ops.wm.save_mainfile()
    assert not rebuilt.exists()
    assert sorted(p.name for p in orig_vdb.parent.iterdir()) == [f"orig.{study}.vdb"]

    # the original reopens with its volume
    assert _loads(ext, orig, vname) == orig_vdb

    # ... and the same from the original's side: removing its study there leaves a Save As copy whole
    bpy.ops.wm.save_as_mainfile(filepath=str(copy))
    assert _vdb_of(bpy.data.objects[vname]).name == f"copy.{study}.vdb"
    bpy.ops.wm.open_mainfile(filepath=str(orig))
    ext.study.entity.Study.of(bpy.data.collections[study]).remove()
    bpy.ops.wm.save_mainfile()
    assert not orig_vdb.exists()
    assert _loads(ext, copy, vname).name == f"copy.{study}.vdb"


def test_a_tampered_record_of_vdb_files_deletes_only_this_files_own(ext, tmp_path):
    import bpy
    other = tmp_path / "other.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(other))
    _, other_vol = _study_with_volume(ext)
    other_name = other_vol.name
    bpy.ops.wm.save_mainfile()
    others_vdb = _vdb_of(other_vol)
    assert others_vdb.is_file() and others_vdb.name.startswith("other.")

    bpy.ops.wm.read_homefile(use_empty=True)
    mine = tmp_path / "mine.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(mine))
    _, my_vol = _study_with_volume(ext)
    foreign = tmp_path / "pdehead_vdb" / "someone_else.vdb"
    foreign.write_bytes(others_vdb.read_bytes())
    outside = tmp_path / "elsewhere.vdb"
    outside.write_bytes(b"not ours")
    bpy.context.scene.pdehead.vdb_files = json.dumps(
        [str(others_vdb), str(foreign), str(outside), "/etc/passwd", 42, {"a": 1}, "x" * 10000])
    bpy.ops.wm.save_mainfile()
    assert others_vdb.is_file() and foreign.is_file() and outside.read_bytes() == b"not ours"
    my_vdb = _vdb_of(my_vol)
    assert my_vdb.is_file() and my_vdb.name.startswith("mine.")
    assert _loads(ext, other, other_name) == others_vdb
    # not a list at all: nothing is deleted, the save works
    bpy.ops.wm.open_mainfile(filepath=str(mine))
    bpy.context.scene.pdehead.vdb_files = "{not json"
    bpy.ops.wm.save_mainfile()
    assert others_vdb.is_file() and my_vdb.is_file()


def test_a_volume_path_outside_its_folder_is_never_copied_nor_read(ext, tmp_path):
    import bpy
    blend = tmp_path / "a" / "t.blend"
    blend.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    good, good_vol = _study_with_volume(ext)
    bad, bad_vol = _study_with_volume(ext)
    good_name, bad_name, good_vname, bad_vname = good.name, bad.name, good_vol.name, bad_vol.name
    secret = tmp_path / "secret.txt"
    secret.write_text("private")
    bad_vol.data.filepath = str(secret)
    fake = tmp_path / "fake.vdb"  # a .vdb name, not an OpenVDB file, outside the folder
    fake.write_text("private")

    # Save As into another folder: the good volume is copied, the bad path is not; one report for its study
    target = tmp_path / "b" / "t.blend"
    target.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(target))
    copied = sorted(p.name for p in (target.parent / "pdehead_vdb").iterdir())
    assert copied == [f"t.{good_name}.vdb"]
    bad_warnings = ext.study.entity.Study.of(bad).warnings
    assert len(bad_warnings) == 1 and "not copied" in bad_warnings[0] and str(secret) in bad_warnings[0]
    assert not any("not copied" in w for w in ext.study.entity.Study.of(good).warnings)
    bad_vol.data.filepath = str(fake)
    bpy.ops.wm.save_mainfile()
    assert sorted(p.name for p in (target.parent / "pdehead_vdb").iterdir()) == [f"t.{good_name}.vdb"]

    # reopened: the bad volume's path is cleared with one report, the good one loads
    bad_vol.data.filepath = "/etc/passwd"
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(target))
    assert bpy.data.objects[bad_vname].data.filepath == ""
    report = [w for w in ext.study.entity.Study.of(bpy.data.collections[bad_name]).warnings if "cleared" in w]
    assert len(report) == 1 and "/etc/passwd" in report[0] and bad_vname in report[0]
    assert not any("cleared" in w for w in ext.study.entity.Study.of(bpy.data.collections[good_name]).warnings)
    assert ext.volume.volume.check_volume(bpy.data.objects[good_vname]) is None
    assert secret.read_text() == "private" and fake.read_text() == "private"
