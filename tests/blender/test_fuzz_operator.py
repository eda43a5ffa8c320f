"""Issue 40's fuzz suite in Blender: 20 refused inputs of ``scripts/fuzz_inputs.py`` through the Import CT
operator in one bpy process. Each must end in a report naming the problem (``RuntimeError`` from
``bpy.ops``), no Python traceback, and nothing created in the file."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
import fuzz_inputs  # noqa: E402
from datasets import shared_data  # noqa: E402


@pytest.fixture(scope="module")
def refused(tmp_path_factory):
    """12 refused GE DICOM cases and 8 refused TIFF stacks (folders), with their load_ct message."""
    shared_data("ct_head_ge_tilt_dicom", "dicom")
    shared_data("cthead_stanford", "raw16")
    root = tmp_path_factory.mktemp("fuzz-op")
    chosen = []
    for source, count in (("dicom", 12), ("tiff", 8)):
        cases = fuzz_inputs.make_cases(root, seed=1, sources=(source,))
        picked = 0
        for case in cases[::3]:                      # spread over the kinds of mutation
            if picked == count or not case.path.is_dir():
                continue
            r = fuzz_inputs.run_case(case)
            if r["outcome"] == "error":
                chosen.append((case, r["message"]))
                picked += 1
    assert len(chosen) == 20, len(chosen)
    return chosen


def test_twenty_refused_inputs_through_the_import_operator(ext, refused):
    import bpy
    for case, message in refused:
        options = {"use_spacing": True, "spacing": (2.0, 1.0, 1.0)} if case.source == "TIFF stack" else {}
        with pytest.raises(RuntimeError) as info:
            bpy.ops.pdehead.import_ct(directory=str(case.path), **options)
        text = str(info.value)
        problem = message.split(": ", 1)[-1][:60]
        assert problem in text, (case.name, problem, text)
        assert "Traceback" not in text, (case.name, text)
        assert len(bpy.data.collections) == 0 and len(bpy.data.objects) == 0, case.name
    assert ext.state.studies() == []
