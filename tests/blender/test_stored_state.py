"""The .blend's stored study state is data (operators/study/persistence.py's load checks, study_entity.parse_timings,
the payload budgets of pdehead_addon/defaults.py): a tampered file ends in one clear report per study and the
rest of the file keeps working."""
from __future__ import annotations

import base64
import json
import struct
import zlib

import pytest


def _pipeline(bpy):
    assert bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=4, nu=16, nv=24, nw=3, build_volume=False) \
        == {'FINISHED'}
    return bpy.context.scene.pdehead.active_study


def _boundary_bomb(ext, good_b64: str, inflated: int) -> str:
    storage = ext.engine.io.storage
    good = base64.b64decode(good_b64)
    hlen = storage._FIXED.unpack_from(good, 0)[2]
    header = good[storage._FIXED.size:storage._FIXED.size + hlen]
    packed = zlib.compress(b"\0" * inflated, 9)
    raw = b"".join([storage._FIXED.pack(storage.MAGIC, storage.VERSION, len(header)), header,
                    storage._PAYLOAD.pack(len(packed), zlib.crc32(header + packed)), packed])
    return base64.b64encode(raw).decode("ascii")


def test_a_tampered_file_gives_one_report_per_study_and_the_rest_works(ext, tmp_path):
    import bpy
    D = ext.engine.defaults
    blend = tmp_path / "t.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bombed, clamped = _pipeline(bpy), _pipeline(bpy)
    bombed_name, clamped_name = bombed.name, clamped.name
    # the tampering: a zlib bomb as the boundary payload and as the CT table (64 MB + 1 each from ~70 kB),
    # numbers beyond the properties' limits, timings that are no table
    bombed[ext.state.BOUNDARY_KEY] = _boundary_bomb(ext, bombed[ext.state.BOUNDARY_KEY],
                                                    D.MAX_STORED_BOUNDARY_BYTES.default * 4)
    header = json.dumps({"format": ext.engine.SolidCTTable.PACK_FORMAT, "shape": [1024, 1024, 64],
                         "window": [0, 1], "range": [0, 1]}).encode()
    too_big = b"\0" * (D.MAX_STORED_CT_TABLE_BYTES.default + 1)
    table = struct.pack("<I", len(header)) + header + zlib.compress(too_big, 9)
    bombed[ext.state.CT_TABLE_KEY] = base64.b64encode(table).decode("ascii")
    s = ext.state.settings(clamped)
    s["nu"] = 100_000_000                      # an IDProperty write: Blender's limits do not apply
    s["nv"] = -5
    s.timings_json = "[not json"
    ext.state.settings(bombed).timings_json = json.dumps({"segment": "x", "pde": float("nan")})
    bpy.ops.wm.save_mainfile()

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    bombed, clamped = bpy.data.collections[bombed_name], bpy.data.collections[clamped_name]
    for coll in (bombed, clamped):
        ext.state.drop_cache(ext.state.settings(coll).study_id)
    s = ext.state.settings(clamped)
    assert (s.nu, s.nv) == (D.NU.max, D.NV.min)
    Study = ext.study.entity.Study
    reports = [w for w in Study.of(clamped).warnings if "outside their limits" in w]
    assert len(reports) == 1 and "nu 1e+08 -> 400" in reports[0] and "nv -5 -> 4" in reports[0], reports
    assert "timings" in reports[0] and Study.of(clamped).timings == {}
    assert Study.of(bombed).timings == {}      # non-numbers dropped; reading never raises

    # the bombed study: one clear error naming the budget, no gigabytes allocated
    bpy.context.scene.pdehead.active_study = bombed
    with pytest.raises(RuntimeError) as info:
        bpy.ops.pdehead.reconstruct_surface()
    message = str(info.value)
    assert f"study '{bombed_name}'" in message and "budget" in message and "internal" not in message.lower(), message
    assert Study.of(bombed).load_stored_ct_table() is None   # the bombed CT table reads as none
    # the other study works: its surface rebuilds within the clamped limits
    bpy.context.scene.pdehead.active_study = clamped
    assert bpy.ops.pdehead.reconstruct_surface(nu=16, nv=24) == {'FINISHED'}
    assert len(s.surface_object.data.vertices) > 16 * 24 // 2

