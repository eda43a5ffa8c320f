"""Nothing is written into the user's input (pdehead_addon.io.export.input_folder_conflict): the rule the CLI
checks before the work and Export for Printing checks again."""
from pdehead_addon.io.export import input_folder_conflict


def test_a_folder_input_refuses_itself_and_any_folder_inside(tmp_path):
    series = tmp_path / "dicom"
    series.mkdir()
    assert "input folder" in input_folder_conflict(series, series)
    assert "input folder" in input_folder_conflict(series / "out" / "face", series)
    assert input_folder_conflict(tmp_path / "out", series) is None           # beside it: fine
    assert input_folder_conflict(tmp_path / "dicom-out", series) is None     # a name that starts the same


def test_a_file_input_refuses_its_own_folder_only(tmp_path):
    """README's `--skull-mesh skull.stl --export out/face`, run in the mesh's folder, was refused after the work."""
    mesh = tmp_path / "skull.stl"
    mesh.write_bytes(b"solid x\nendsolid x\n")
    assert "beside the input file skull.stl" in input_folder_conflict(tmp_path, mesh)
    assert input_folder_conflict(tmp_path / "out" / "face", mesh) is None
    assert input_folder_conflict(tmp_path.parent / "elsewhere", mesh) is None
    assert input_folder_conflict(tmp_path / "out", None) is None             # the phantom: no input
