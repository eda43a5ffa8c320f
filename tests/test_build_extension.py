"""Issue 18, point 6: the extension zip always carries what it needs.

Builds run as a user runs them (``scripts/build_extension.py --platform linux-x64``) against a temporary
copy of the wheel cache (``PDEHEAD_CACHE``): the shared cache is never written by these tests. A copy
made from a complete cache builds offline; otherwise the build downloads what is missing into the copy.
"""
from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "build_extension.py"
sys.path.insert(0, str(ROOT / "scripts"))
import build_extension as B  # noqa: E402

PLATFORM = "linux-x64"
PYTHONS = {"3.11": "cp311", "3.13": "cp313"}


def wheel_cache_copy(root: Path, index: bool = False) -> Path:
    """A private PDEHEAD_CACHE holding copies of the linux-x64 wheels of the real cache (never linked)."""
    for python, tag in PYTHONS.items():
        dest = root / "wheels" / PLATFORM / tag
        dest.mkdir(parents=True)
        source = B.WHEEL_CACHE / PLATFORM / tag
        for req in B.shipped_requirements(python):
            for wheel in source.glob("*.whl") if source.is_dir() else ():
                if B.wheel_fits(wheel.name, req, python, PLATFORM):
                    shutil.copy2(wheel, dest / wheel.name)
    return root


def build(cache: Path, out: Path, **popen):
    env = dict(os.environ, PDEHEAD_CACHE=str(cache))
    cmd = [sys.executable, str(SCRIPT), "--platform", PLATFORM, "--output-dir", str(out)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, **popen)


def finish(proc) -> tuple[int, str]:
    stdout, stderr = proc.communicate(timeout=1800)
    return proc.returncode, stdout + stderr


def wheel_names(zip_path: Path) -> list[str]:
    with zipfile.ZipFile(zip_path) as z:
        return sorted(n.split("/", 1)[1] for n in z.namelist() if n.startswith("wheels/"))


def index_key(req: str) -> str:
    return f"{req} {','.join(B.PLATFORM_TAGS[PLATFORM])}"


def test_the_validation_package_stays_out_of_the_zip(tmp_path):
    """Issue 25: the zip ships the engine's subpackages but not pdehead_addon/validation/ (tests and
    benchmarks only), and no shipped engine module imports it."""
    stage = tmp_path / "stage"
    B.stage_sources(stage)
    engine = stage / "pdehead_addon"
    assert (ROOT / "pdehead_addon" / "validation" / "metrics.py").is_file()      # it exists in the repo ...
    assert not (engine / "validation").exists()                                 # ... and is not staged
    for sub in ("core", "io", "segment", "curves", "pde", "forensic"):
        assert (engine / sub / "__init__.py").is_file(), sub
    assert (engine / "io" / "ct_import" / "load.py").is_file() and (engine / "forensic" / "data").is_dir()
    shipped = sorted(engine.rglob("*.py"))
    assert len(shipped) > 30
    imports = [(p.relative_to(stage).as_posix(), node.lineno) for p in shipped
               for node in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
               if isinstance(node, ast.ImportFrom) and "validation" in (node.module or "").split(".")
               or isinstance(node, ast.Import) and any("validation" in a.name.split(".") for a in node.names)]
    assert imports == []


def test_wheels_are_chosen_by_file_name():
    tags = "cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64"
    assert B.wheel_fits(f"scikit_image-0.26.0-{tags}.whl", "scikit-image==0.26.0", "3.11", PLATFORM)
    assert not B.wheel_fits(f"scipy-1.17.1-{tags}.whl", "scikit-image==0.26.0", "3.11", PLATFORM)
    assert not B.wheel_fits(f"scikit_image-0.25.2-{tags}.whl", "scikit-image==0.26.0", "3.11", PLATFORM)
    assert not B.wheel_fits(f"scikit_image-0.26.0-{tags}.whl", "scikit-image==0.26.0", "3.13", PLATFORM)
    assert not B.wheel_fits("scikit_image-0.26.0-cp311-cp311-win_amd64.whl", "scikit-image==0.26.0", "3.11",
                            PLATFORM)
    assert B.wheel_fits("scikit_image-0.26.0-cp311-cp311-win_amd64.whl", "scikit-image==0.26.0", "3.11",
                        "windows-x64")
    assert B.wheel_fits("lazy_loader-0.6-py3-none-any.whl", "lazy-loader==0.6", "3.13", PLATFORM)
    # manylinux_2_34 is newer than any tag the linux zip allows (glibc 2.28, 2.31 for libjpeg)
    assert not B.wheel_fits("pillow-13.0.0-cp311-cp311-manylinux_2_34_x86_64.whl", "pillow==13.0.0", "3.11",
                            PLATFORM)
    assert B.wheel_fits("pillow-13.0.0-cp311-cp311-macosx_11_0_arm64.whl", "pillow==13.0.0", "3.11",
                        "macos-arm64")


def test_poisoned_index_is_repaired_and_the_zip_verifies(tmp_path):
    """The shared cache's index once recorded the scipy wheel under scikit-image==0.26.0 (two builds at
    once); every zip built after lacked scikit-image. The index is repaired, the zip carries it."""
    cache = wheel_cache_copy(tmp_path / "cache")
    pins = B.read_pins()
    skimage = f"scikit-image=={pins['scikit-image']}"
    for _python, tag in PYTHONS.items():
        folder = cache / "wheels" / PLATFORM / tag
        scipy = next(p.name for p in folder.glob("scipy-*.whl"))
        (folder / "index.json").write_text(json.dumps({index_key(skimage): scipy}))
    code, log = finish(build(cache, tmp_path / "dist"))
    assert code == 0, log[-3000:]
    assert f"repaired the cache index: {skimage} pointed at scipy-" in log
    [zip_path] = list((tmp_path / "dist").glob("*.zip"))
    assert B.verify_zip(zip_path) == []
    names = wheel_names(zip_path)
    for tag in PYTHONS.values():
        assert len([n for n in names if n.startswith(f"scikit_image-{pins['scikit-image']}-{tag}-")]) == 1, names
        index = json.loads((cache / "wheels" / PLATFORM / tag / "index.json").read_text())
        assert index[index_key(skimage)].startswith("scikit_image-"), index
    # the verifier refuses the zip the poisoned cache used to give: no scikit-image for one Python
    broken = tmp_path / "pdehead-0.1.0-linux_x64.zip"
    with zipfile.ZipFile(zip_path) as src, zipfile.ZipFile(broken, "w") as dst:
        for item in src.infolist():
            if not item.filename.startswith("wheels/scikit_image-") or "cp311" not in item.filename:
                dst.writestr(item, src.read(item.filename))
    problems = B.verify_zip(broken)
    assert any(p.startswith(f"{skimage} for Python 3.11: 0 wheels") for p in problems), problems


def test_wheel_that_is_not_what_its_name_says_is_refused(tmp_path):
    """A cached file named like scikit-image but holding scipy: the build fails and writes no zip."""
    cache = wheel_cache_copy(tmp_path / "cache")
    folder = cache / "wheels" / PLATFORM / "cp311"
    impostor = next(folder.glob("scikit_image-*.whl"))
    shutil.copy2(next(folder.glob("scipy-*.whl")), impostor)
    code, log = finish(build(cache, tmp_path / "dist"))
    assert code != 0 and impostor.name in log and "its METADATA says scipy" in log, log[-3000:]
    assert not list((tmp_path / "dist").glob("*.zip")) and "Traceback" not in log


def assert_repository_lists(folder: Path, zip_names: list[str]) -> None:
    """``folder/index.json`` is a Blender remote-repository listing of exactly ``zip_names``: each entry's
    relative archive URL, size and sha256 hash those of the file beside it, its id and platforms the zip's."""
    import hashlib
    index = json.loads((folder / "index.json").read_text())
    assert index["version"] == "v1", index
    entries = index["data"]
    assert sorted(e["archive_url"] for e in entries) == sorted(f"./{n}" for n in zip_names), entries
    for entry in entries:
        path = folder / entry["archive_url"][2:]
        assert entry["id"] == "pdehead" and entry["type"] == "add-on", entry
        assert entry["archive_size"] == path.stat().st_size
        assert entry["archive_hash"] == "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
        assert entry["platforms"] == [B.zip_platform(path)], entry
    assert "pdehead" in (folder / "index.html").read_text()
    assert not [p for p in folder.iterdir() if p.name.startswith(".")], list(folder.iterdir())


INSTALL_FROM_REPOSITORY = """
import os, sys
os.environ["BLENDER_USER_RESOURCES"] = sys.argv[2]
import bpy
prefs = bpy.context.preferences
prefs.system.use_online_access = True
repo_dir = os.path.join(sys.argv[2], "repo")
prefs.extensions.repos.new(name="PDE Head", module="pdehead_dist", custom_directory=repo_dir, remote_url=sys.argv[1])
assert bpy.ops.extensions.repo_sync_all() == {"FINISHED"}
index = next(i for i, r in enumerate(prefs.extensions.repos) if r.module == "pdehead_dist")
assert bpy.ops.extensions.package_install(repo_index=index, pkg_id="pdehead") == {"FINISHED"}
assert os.path.isfile(os.path.join(repo_dir, "pdehead", "blender_manifest.toml"))
print("enabled:", *[m for m in prefs.addons.keys() if m.endswith(".pdehead")])
"""


def test_repository_index_follows_the_folder(tmp_path):
    """A build writes the folder's repository index (regenerated the same way when asked again); with
    --no-repository-index only the zip is written; a folder without a zip gets no index but an error."""
    dist = tmp_path / "dist"
    dist.mkdir()
    cache = wheel_cache_copy(tmp_path / "cache")
    code, log = finish(build(cache, dist))
    assert code == 0, log[-3000:]
    [zip_path] = list(dist.glob("*.zip"))
    assert f"repository index: {dist / 'index.json'}" in log
    assert_repository_lists(dist, [zip_path.name])
    B.write_repository_index(dist)  # idempotent: the same listing
    assert_repository_lists(dist, [zip_path.name])
    # Blender, as a user sets it up: the folder's index.json added as a remote repository, synced, and the
    # extension installed from it (in a child process: this one may have the extension installed already)
    result = subprocess.run([sys.executable, "-c", INSTALL_FROM_REPOSITORY, (dist / "index.json").as_uri(),
                             str(tmp_path / "user")], capture_output=True, text=True, timeout=1200)
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    assert "enabled: bl_ext.pdehead_dist.pdehead" in result.stdout, result.stdout[-3000:]
    bare = tmp_path / "bare"
    env = dict(os.environ, PDEHEAD_CACHE=str(cache))
    result = subprocess.run([sys.executable, str(SCRIPT), "--platform", PLATFORM, "--output-dir", str(bare),
                             "--no-repository-index"], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert sorted(p.name for p in bare.iterdir()) == [zip_path.name]
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SystemExit, match="no extension zip"):
        B.write_repository_index(empty)


def test_two_builds_at_once_give_identical_verified_zips(tmp_path):
    """Two builds started together on one cache (no index yet) and one source tree."""
    cache = wheel_cache_copy(tmp_path / "cache")
    procs = [build(cache, tmp_path / f"dist{i}") for i in (1, 2)]
    results = [finish(p) for p in procs]
    for code, log in results:
        assert code == 0, log[-3000:]
    zips = [next((tmp_path / f"dist{i}").glob("*.zip")) for i in (1, 2)]
    assert zips[0].name == zips[1].name == "pdehead-0.1.0-linux_x64.zip"
    assert zips[0].read_bytes() == zips[1].read_bytes()
    assert B.verify_zip(zips[0]) == []
    for folder in (tmp_path / "dist1", tmp_path / "dist2"):
        assert_repository_lists(folder, [zips[0].name])
    # and a build started later, on the now-indexed cache, gives the same bytes (no build time in the zip)
    code, log = finish(build(cache, tmp_path / "dist3"))
    assert code == 0, log[-3000:]
    assert (tmp_path / "dist3" / zips[0].name).read_bytes() == zips[0].read_bytes()
    names = wheel_names(zips[0])
    for python in PYTHONS:
        for req in B.shipped_requirements(python):
            assert sum(B.wheel_fits(n, req, python, PLATFORM) for n in names) == 1, (req, python, names)
    for tag in PYTHONS.values():
        index = json.loads((cache / "wheels" / PLATFORM / tag / "index.json").read_text())
        python = next(p for p, t in PYTHONS.items() if t == tag)
        assert all(B.wheel_fits(wheel, key.split()[0], python, PLATFORM) for key, wheel in index.items()), index
