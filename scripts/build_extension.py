#!/usr/bin/env python3
"""Build the PDE Head Blender extension: one zip per platform with the engine's wheels inside.

Usage::

    python3 scripts/build_extension.py                       # all four platforms -> dist/
    python3 scripts/build_extension.py --platform linux-x64  # only one (what the tests use)
    python3 scripts/build_extension.py --output-dir /tmp/out --platform linux-x64

What it does:

1. downloads, once, the wheels of the engine's dependencies for each platform and each
   Python that a supported Blender embeds (3.11 for Blender 4.2 - 5.0, 3.13 for 5.1+) with
   ``pip download --only-binary=:all: --platform ... --python-version 3.x --no-deps``
   into ``~/.cache/pdehead/wheels/<platform>/cp3xx/`` (``$PDEHEAD_CACHE/wheels``; reused offline).
   numpy is *not* shipped: Blender brings its own (1.26 up to 5.0, 2.x from 5.1).
   Blender installs only the wheels matching its own Python and platform, so one zip
   per platform serves every Blender from 4.2 to 5.3.
2. copies the shipped sources (root ``__init__.py``, ``operators/``, ``pdehead_addon/`` without
   ``pdehead_addon/validation/``, the measures used by tests and benchmarks only)
   into ``build/extension_src/`` with the wheels, and writes a build copy of
   ``blender_manifest.toml`` there that lists the ``wheels`` and ``platforms``
   (the tracked manifest is never modified, so the repo stays clean).
3. runs Blender's own extension builder (``bl_pkg/cli/blender_ext.py build
   --split-platforms``) from the installed ``bpy`` package.
4. writes a remote-repository index for the output folder with the same tool's ``server-generate``
   (``index.json`` and a browsable ``index.html``): every extension zip in the folder is listed with
   its platforms, size and hash, so the folder, served over HTTP or as a local path, can be added in
   Blender's *Preferences > Get Extensions > Repositories > Add Remote Repository* and Blender offers
   the update when a newer zip appears there. ``--no-repository-index`` leaves it out.

Prints the path of every zip built, one per line, after "built:", then the index's path.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUILD = ROOT / "build"
# Downloaded wheels are kept outside the clone (beside the project venvs, see scripts/venv.sh),
# so a fresh clone builds offline once they are there.
WHEEL_CACHE = Path(os.environ.get("PDEHEAD_CACHE")
                   or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pdehead") / "wheels"

# Blender platform -> pip --platform tags (pip also accepts older manylinux/macOS versions).
PLATFORM_TAGS: dict[str, list[str]] = {
    # Blender 4.2+ needs glibc 2.28; manylinux_2_31 (last, so only taken when nothing older exists)
    # is for pylibjpeg-libjpeg 2.5.0, whose only Linux wheel needs glibc 2.31 (Ubuntu 20.04+, Debian 11+).
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
                  "manylinux_2_31_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_14_0_arm64", "macosx_12_0_arm64", "macosx_11_0_arm64"],
    "macos-x64": ["macosx_14_0_x86_64", "macosx_10_14_x86_64", "macosx_10_9_x86_64"],
}
# Python of each supported Blender: 4.2 - 5.0 embed 3.11, 5.1 - 5.3 embed 3.13.
PYTHON_VERSIONS = ("3.11", "3.13")

# The engine's direct requirements are pinned in requirements.txt; their own dependencies
# (from `pip show` / the wheels' Requires-Dist) are pinned here to the versions tested with.
ENGINE_REQUIREMENTS = ("scikit-image", "scipy", "pydicom")
# pydicom's decoders for compressed DICOM (JPEG, JPEG-LS, JPEG 2000); shipped when pinned in
# requirements.txt. A platform/Python without a wheel for one of them is reported by the build
# (the zip then lacks that decoder there and the engine says so when it meets such a file).
DECODER_REQUIREMENTS = ("pylibjpeg", "pylibjpeg-openjpeg", "pylibjpeg-libjpeg")
TRANSITIVE_PINS = {
    # scikit-image 0.26.0 requires these (numpy excluded: Blender ships it)
    "imageio": "2.38.1",
    "lazy-loader": "0.6",
    "networkx": "3.6.1",
    "packaging": "26.2",
    "pillow": "13.0.0",
    "tifffile": "2026.3.3",
}
NOT_SHIPPED = {"numpy"}
SHIPPED_SOURCES = ("__init__.py", "operators", "pdehead_addon", "LICENSE", "LICENSE.txt", "README.md")
#: Folders of the shipped sources left out of the zip: the engine's measures for tests and benchmarks.
NOT_SHIPPED_SOURCES = ("pdehead_addon/validation",)


def _python(python: str | None) -> str:
    return python or "%d.%d" % sys.version_info[:2]


def read_pins(requirements: Path = ROOT / "requirements.txt", python: str | None = None) -> dict[str, str]:
    """name -> version of every ``name==version`` line of requirements.txt (names lower-case).

    Lines with an environment marker (``; python_version < "3.13"``) count only for the
    Python they select: ``python`` ("3.11", "3.13"), default the running one.
    """
    from packaging.markers import Marker

    pins = {}
    for line in requirements.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        m = re.fullmatch(r"([A-Za-z0-9_.\-]+)\s*==\s*([^\s;]+)\s*(?:;\s*(.+))?", line)
        if m and (not m.group(3) or Marker(m.group(3)).evaluate({"python_version": _python(python)})):
            pins[m.group(1).lower().replace("_", "-")] = m.group(2)
    return pins


def shipped_requirements(python: str | None = None) -> list[str]:
    """``name==version`` of every wheel the extension ships for ``python`` (engine pins + their dependencies)."""
    pins = read_pins(python=python)
    missing = [name for name in ENGINE_REQUIREMENTS if name not in pins]
    if missing:
        raise SystemExit(f"requirements.txt: no '==' pin for {', '.join(missing)}")
    reqs = {name: pins[name] for name in ENGINE_REQUIREMENTS + DECODER_REQUIREMENTS if name in pins}
    reqs.update(TRANSITIVE_PINS)
    return [f"{name}=={version}" for name, version in sorted(reqs.items()) if name not in NOT_SHIPPED]


def _wheel_tag(python: str) -> str:
    return "cp" + python.replace(".", "")


# ----------------------------------------------------------------------------- wheels by their file names
def canonical_name(name: str) -> str:
    """PEP 503 normalised project name: 'Scikit_Image' -> 'scikit-image'."""
    return re.sub(r"[-_.]+", "-", name).lower()


def parse_wheel_name(filename: str) -> dict | None:
    """name, version, python / abi / platform tag sets of a wheel file name (PEP 427), or None."""
    m = re.fullmatch(r"([^-]+)-([^-]+)(?:-(\d[^-]*))?-([^-]+)-([^-]+)-([^-]+)\.whl", filename)
    if not m:
        return None
    return {"name": canonical_name(m.group(1)), "version": m.group(2), "python": set(m.group(4).split(".")),
            "abi": set(m.group(5).split(".")), "platform": set(m.group(6).split("."))}


def _platform_ok(tags: set[str], platform: str) -> bool:
    """A wheel's platform tags fit ``platform``: 'any', or the family and architecture of one of its pip
    tags at a version not newer than the newest listed (manylinux2014 = manylinux_2_17)."""
    if "any" in tags:
        return True
    aliases = {"manylinux1": (2, 5), "manylinux2010": (2, 12), "manylinux2014": (2, 17)}

    def split(tag):
        m = re.fullmatch(r"(manylinux1|manylinux2010|manylinux2014)_(\w+)", tag)
        if m:
            return ("manylinux",) + aliases[m.group(1)] + (m.group(2),)
        m = re.fullmatch(r"(manylinux|macosx)_(\d+)_(\d+)_(\w+)", tag)
        return (m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)) if m else (tag, 0, 0, "")

    allowed = [split(t) for t in PLATFORM_TAGS[platform]]
    for tag in tags:
        family, major, minor, arch = split(tag)
        for a_family, a_major, a_minor, a_arch in allowed:
            if family == a_family and (major, minor) <= (a_major, a_minor) and (
                    arch == a_arch or (family == "macosx" and arch == "universal2")):
                return True
            if family == a_family == tag and arch == a_arch == "":  # e.g. win_amd64
                return True
    return False


def wheel_fits(filename: str, requirement: str, python: str, platform: str) -> bool:
    """Whether the wheel file ``filename`` is ``name==version`` for ``python`` ("3.11") on ``platform``."""
    info = parse_wheel_name(filename)
    if info is None:
        return False
    name, version = requirement.split("==")
    cp = _wheel_tag(python)
    python_ok = bool(info["python"] & {cp, "py3", f"py{python.replace('.', '')}"}) or (
        "abi3" in info["abi"] and any(t.startswith("cp3") and int(t[3:] or 0) <= int(cp[3:]) for t in info["python"]))
    return (info["name"] == canonical_name(name) and info["version"] == version and python_ok
            and _platform_ok(info["platform"], platform))


def wheel_metadata_matches(path: Path) -> str | None:
    """None when the wheel is a readable zip whose METADATA names the project and version its file name
    says; else what is wrong (a renamed or truncated file in the cache)."""
    import zipfile
    info = parse_wheel_name(path.name)
    if info is None:
        return "not a wheel file name"
    try:
        with zipfile.ZipFile(path) as z:
            metas = [n for n in z.namelist() if re.fullmatch(r"[^/]+\.dist-info/METADATA", n)]
            if len(metas) != 1:
                return f"{len(metas)} METADATA files inside"
            text = z.read(metas[0]).decode("utf-8", "replace")
    except (OSError, zipfile.BadZipFile, KeyError) as exc:
        return f"not a readable wheel ({exc})"
    fields = dict(re.findall(r"^(Name|Version): *(\S+)", text, flags=re.M))
    if canonical_name(fields.get("Name", "")) != info["name"] or fields.get("Version") != info["version"]:
        return f"its METADATA says {fields.get('Name')} {fields.get('Version')}"
    return None


def _pick(folder: Path, requirement: str, python: str, platform: str) -> Path | None:
    """The cached wheel for the requirement, chosen by file name (deterministic: the first by name)."""
    found = sorted(p for p in folder.glob("*.whl") if wheel_fits(p.name, requirement, python, platform))
    return found[0] if found else None


@contextlib.contextmanager
def _locked(folder: Path):
    """An exclusive lock on the cache folder: concurrent builds take turns (no torn index, no half wheel)."""
    lock = open(folder / ".lock", "a+")
    try:
        try:
            import fcntl
            fcntl.flock(lock, fcntl.LOCK_EX)
        except ImportError:  # pragma: no cover - Windows: no fcntl; downloads still land atomically
            pass
        yield
    finally:
        lock.close()  # releases the lock


def _write_index(index_path: Path, index: dict) -> None:
    tmp = index_path.with_name(f".{index_path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(index, indent=1, sort_keys=True))
    os.replace(tmp, index_path)


def download_wheels(platform: str, python: str, requirements: list[str],
                    optional: set[str] = frozenset()) -> tuple[list[Path], list[str]]:
    """Wheels for ``platform`` and ``python`` in WHEEL_CACHE/<platform>/cp3xx/, downloading only what is not cached.

    Every wheel is found by its file name (project, version, Python and platform tags: PEP 427), never
    by what appeared in the folder, and its METADATA must agree with that name; ``index.json`` only
    remembers which optional requirements have no wheel here. An index entry that names a wheel not
    fitting its requirement (a cache written by the old builder, or by two builds at once) is repaired
    and said. A download goes to a private temporary folder and is moved in atomically, under a lock
    on the cache folder, so builds may run at the same time.

    Returns ``(wheels, missing)``: ``missing`` lists the requirements in ``optional`` (by name)
    that have no wheel for this platform and Python; any other missing wheel stops the build.
    """
    folder = WHEEL_CACHE / platform / _wheel_tag(python)
    folder.mkdir(parents=True, exist_ok=True)
    index_path = folder / "index.json"
    wheels, missing = [], []
    tags = ",".join(PLATFORM_TAGS[platform])
    with _locked(folder):
        try:
            index = json.loads(index_path.read_text()) if index_path.exists() else {}
        except (OSError, ValueError):
            print(f"[{platform} {_wheel_tag(python)}] unreadable {index_path}: rebuilt", flush=True)
            index = {}
        changed = False
        for req in requirements:
            key = f"{req} {tags}"  # a change of platform tags looks again
            name = req.split("==")[0].lower()
            cached = index.get(key)
            if cached and not wheel_fits(cached, req, python, platform):
                print(f"[{platform} {_wheel_tag(python)}] repaired the cache index: {req} pointed at {cached}",
                      flush=True)
                index[key] = cached = None
                changed = True
            wheel = _pick(folder, req, python, platform)
            if wheel is not None:
                problem = wheel_metadata_matches(wheel)
                if problem:
                    raise SystemExit(f"cached wheel {wheel} is not {req} for {platform} / Python {python}: "
                                     f"{problem}; delete it and build again")
                if index.get(key) != wheel.name:
                    index[key], changed = wheel.name, True
                wheels.append(wheel)
                continue
            if cached == "" and name in optional:  # known to have no wheel here
                missing.append(req)
                continue
            wheel = _download(folder, platform, python, req, name in optional)
            if wheel is None:
                index[key], changed = "", True
                missing.append(req)
                continue
            index[key], changed = wheel.name, True
            wheels.append(wheel)
        if changed:
            _write_index(index_path, index)
    return wheels, missing


def _download(folder: Path, platform: str, python: str, req: str, optional: bool) -> Path | None:
    """``pip download`` one requirement into a private folder, pick the wheel by file name and move it
    into the cache atomically; None when an optional requirement has no wheel here."""
    import tempfile
    with tempfile.TemporaryDirectory(prefix=".download-", dir=folder) as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
               "--only-binary=:all:", "--no-deps", "--python-version", python,
               "--implementation", "cp", "--dest", tmp]
        for tag in PLATFORM_TAGS[platform]:
            cmd += ["--platform", tag]
        cmd.append(req)
        print(f"[{platform} {_wheel_tag(python)}] pip download {req}", flush=True)
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode:
            if optional and "No matching distribution" in result.stderr:
                return None
            raise SystemExit(f"pip download {req} for {platform} / Python {python} failed:\n"
                             f"{result.stderr.strip()}")
        got = _pick(Path(tmp), req, python, platform)
        if got is None:
            names = ", ".join(p.name for p in Path(tmp).iterdir()) or "nothing"
            raise SystemExit(f"pip download {req} for {platform} / Python {python} gave no wheel of that "
                             f"name, version and tags ({names})")
        problem = wheel_metadata_matches(got)
        if problem:
            raise SystemExit(f"pip download {req} for {platform} / Python {python}: {got.name}: {problem}")
        target = folder / got.name
        os.replace(got, target)
        return target


def manifest_with_wheels(manifest_text: str, wheel_names: list[str], platforms: list[str]) -> str:
    """The manifest text with top-level ``platforms`` and ``wheels`` keys added (before the first table)."""
    lines = [line for line in manifest_text.splitlines()
             if not re.match(r"\s*(wheels|platforms)\s*=", line)]
    first_table = next((i for i, line in enumerate(lines) if line.lstrip().startswith("[")), len(lines))
    generated = ["# generated by scripts/build_extension.py",
                 "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]",
                 "wheels = ["] + [f'  "./wheels/{name}",' for name in wheel_names] + ["]", ""]
    return "\n".join(lines[:first_table] + generated + lines[first_table:]) + "\n"


def blender_ext_script() -> Path:
    """Blender's extension builder inside the installed bpy package."""
    import importlib.util
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("bpy is not installed (pip install -r requirements.txt)")
    bpy_dir = Path(list(spec.submodule_search_locations)[0])
    candidates = sorted(bpy_dir.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not candidates:
        raise SystemExit(f"Blender's extension builder not found under {bpy_dir}")
    return candidates[-1]


def stage_sources(stage: Path) -> None:
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir(parents=True)
    patterns = shutil.ignore_patterns("__pycache__", "*.pyc", ".*")

    def ignore(folder, names):
        left_out = {n for n in names if (Path(folder) / n).relative_to(ROOT).as_posix() in NOT_SHIPPED_SOURCES}
        return set(patterns(folder, names)) | left_out

    for name in SHIPPED_SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, stage / name, ignore=ignore)
        elif src.is_file():
            shutil.copy2(src, stage / name)


def _normalise_times(stage: Path) -> None:
    """Every staged file and folder gets the newest source time: the zip's bytes depend on the sources
    only (not on when the build ran), so two builds of one tree give identical zips."""
    paths = [p for p in stage.rglob("*")]
    newest = max((p.stat().st_mtime for p in paths if p.is_file() and p.parent.name != "wheels"
                  and p.name != "blender_manifest.toml"), default=0.0)
    newest = max(newest, (ROOT / "blender_manifest.toml").stat().st_mtime)
    for p in paths + [stage]:
        os.utime(p, (newest, newest))


def build(platforms: list[str], output_dir: Path, pythons: tuple[str, ...] = PYTHON_VERSIONS) -> list[Path]:
    """Build one zip per platform into ``output_dir`` and verify each (:func:`verify_zip`).

    The sources are staged in a private folder and the zips are built in another, then moved into
    ``output_dir`` atomically, so builds may run at the same time; a zip that does not verify is
    removed and the build fails.
    """
    import tempfile
    BUILD.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="extension-", dir=BUILD) as private:
        stage, out = Path(private) / "src", Path(private) / "out"
        stage_sources(stage)
        (stage / "wheels").mkdir()
        out.mkdir()
        names, missing = set(), {}
        for platform in platforms:
            for python in pythons:
                wheels, absent = download_wheels(platform, python, shipped_requirements(python),
                                                 optional=set(DECODER_REQUIREMENTS))
                missing[(platform, python)] = set(absent)
                for req in absent:
                    print(f"WARNING: no wheel of {req} for {platform} / Python {python}: "
                          "that decoder is missing from this zip there", flush=True)
                for wheel in wheels:
                    if wheel.name not in names:  # pure-Python wheels serve both Pythons
                        shutil.copy2(wheel, stage / "wheels" / wheel.name)
                        names.add(wheel.name)
        manifest = (ROOT / "blender_manifest.toml").read_text()
        (stage / "blender_manifest.toml").write_text(manifest_with_wheels(manifest, sorted(names), platforms))
        _normalise_times(stage)

        cmd = [sys.executable, str(blender_ext_script()), "build", "--source-dir", str(stage),
               "--output-dir", str(out), "--split-platforms"]
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode:
            raise SystemExit(f"Blender's extension builder failed:\n{result.stdout}\n{result.stderr}")
        zips = sorted(out.glob("*.zip"))
        if len(zips) != len(platforms):
            raise SystemExit(f"expected {len(platforms)} zip(s), the builder wrote {zips}:\n{result.stdout}")
        for z in zips:
            _one_entry_time(z)
            problems = verify_zip(z, pythons, missing)
            if problems:
                raise SystemExit(f"{z.name} does not verify, not written:\n  " + "\n  ".join(problems))
        output_dir.mkdir(parents=True, exist_ok=True)
        final = []
        for z in zips:
            target = output_dir / z.name
            shutil.copy2(z, output_dir / f".{z.name}.{os.getpid()}.tmp")
            os.replace(output_dir / f".{z.name}.{os.getpid()}.tmp", target)
            final.append(target)
    return final


def _one_entry_time(zip_path: Path, reference: str = "__init__.py") -> None:
    """Give every zip entry the (normalised) time of ``reference``, in place.

    Blender's builder writes the manifest it generates with the current time, the only part of the
    zip that depends on when it was built; the DOS time and date fields of its local header and its
    central-directory record are overwritten (no data or CRC changes)."""
    import struct
    import zipfile
    with zipfile.ZipFile(zip_path) as z:
        start, count = z.start_dir, len(z.infolist())
    with open(zip_path, "r+b") as f:
        f.seek(start)
        central = f.read()
        records, pos = [], 0
        for _ in range(count):
            if central[pos:pos + 4] != b"PK\x01\x02":
                return  # not a layout we know: leave the zip as it is
            nlen, xlen, clen = struct.unpack_from("<HHH", central, pos + 28)
            (local,) = struct.unpack_from("<I", central, pos + 42)
            records.append((central[pos + 46:pos + 46 + nlen].decode("utf-8", "replace"), pos, local))
            pos += 46 + nlen + xlen + clen
        stamp = next((central[p + 12:p + 16] for name, p, _ in records if name == reference), None)
        if stamp is None:
            return
        for _name, p, local in records:
            if central[p + 12:p + 16] != stamp:
                f.seek(start + p + 12)
                f.write(stamp)
                f.seek(local + 10)
                f.write(stamp)


def zip_platform(zip_path: Path) -> str | None:
    """'pdehead-0.1.0-linux_x64.zip' -> 'linux-x64' (None if the name has no known platform)."""
    stem = Path(zip_path).stem
    return next((p for p in PLATFORM_TAGS if stem.endswith("-" + p.replace("-", "_"))), None)


def verify_zip(zip_path: Path, pythons: tuple[str, ...] = PYTHON_VERSIONS,
               missing: dict | None = None) -> list[str]:
    """What is wrong with a built zip (empty: nothing).

    Each shipped requirement (:func:`shipped_requirements`) must be there exactly once per Python at its
    pinned version, chosen by the wheels' file names, for the zip's platform (an optional decoder may be
    absent where ``missing[(platform, python)]`` says it has no wheel); every wheel in the zip must be
    listed in its manifest and the other way round, and no wheel may be there that no requirement asks for.
    """
    import tomllib
    import zipfile
    platform = zip_platform(zip_path)
    if platform is None:
        return [f"{Path(zip_path).name}: no platform in the file name"]
    try:
        with zipfile.ZipFile(zip_path) as z:
            names = z.namelist()
            manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
            bad = z.testzip()
    except (OSError, zipfile.BadZipFile, KeyError, ValueError) as exc:
        return [f"{Path(zip_path).name}: unreadable ({exc})"]
    problems = [f"corrupt member {bad}"] if bad else []
    wheels = sorted(n.split("/", 1)[1] for n in names if n.startswith("wheels/") and n.endswith(".whl"))
    listed = sorted(w.removeprefix("./wheels/") for w in manifest.get("wheels", []))
    # Blender's --split-platforms keeps every platform's wheels in each zip's manifest (it installs the ones
    # that fit): a listed wheel may be absent only when it is another platform's
    absent = [w for w in set(listed) - set(wheels)
              if (info := parse_wheel_name(w)) is None or _platform_ok(info["platform"], platform)]
    unlisted = sorted(set(wheels) - set(listed))
    if absent or unlisted:
        problems.append(f"manifest lists {sorted(absent)} for this platform, not in the zip, and the zip holds "
                        f"{unlisted} not in the manifest")
    used = set()
    for python in pythons:
        absent = (missing or {}).get((platform, python), set())
        for req in shipped_requirements(python):
            fits = [w for w in wheels if wheel_fits(w, req, python, platform)]
            used.update(fits)
            if len(fits) != 1 and not (not fits and req in absent):
                problems.append(f"{req} for Python {python}: {len(fits)} wheels ({', '.join(fits) or 'none'})")
    stray = sorted(set(wheels) - used)
    if stray:
        problems.append(f"wheels no requirement asks for: {', '.join(stray)}")
    return problems


def write_repository_index(folder: Path) -> Path:
    """Blender's remote-repository listing of every extension zip in ``folder``: ``index.json`` (and
    ``index.html``), written by Blender's own ``blender_ext.py server-generate``.

    The listing is generated in a private copy of the folder's zips' names and moved in atomically,
    so a server reading the folder never sees a half-written index. Returns the index's path.
    """
    import tempfile
    zips = sorted(folder.glob("*.zip"))
    if not zips:
        raise SystemExit(f"{folder}: no extension zip to list in a repository index")
    with tempfile.TemporaryDirectory(prefix=".repository-", dir=folder) as private:
        staging = Path(private)
        for z in zips:  # links (or copies where links are not allowed): the tool only reads them
            try:
                os.link(z, staging / z.name)
            except OSError:
                shutil.copy2(z, staging / z.name)
        cmd = [sys.executable, str(blender_ext_script()), "server-generate", "--repo-dir", str(staging), "--html"]
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode or not (staging / "index.json").is_file():
            raise SystemExit(f"Blender's server-generate failed for {folder}:\n{result.stdout}\n{result.stderr}")
        for name in ("index.html", "index.json"):  # the JSON last: it is what Blender reads
            if (staging / name).is_file():
                os.replace(staging / name, folder / name)
    return folder / "index.json"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS),
                        help="build only this platform (repeatable); default: all four")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist",
                        help="folder for the zips (created if missing); default: dist/")
    parser.add_argument("--no-repository-index", action="store_true",
                        help="do not write the remote-repository index (index.json, index.html) of the folder")
    args = parser.parse_args(argv)
    platforms = args.platform or list(PLATFORM_TAGS)
    zips = build(platforms, args.output_dir.resolve())
    print("built:")
    for z in zips:
        print(z)
    if not args.no_repository_index:
        print(f"repository index: {write_repository_index(args.output_dir.resolve())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
