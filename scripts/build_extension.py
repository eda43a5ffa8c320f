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
2. copies the shipped sources (root ``__init__.py``, ``operators/``, ``pdehead_addon/``)
   into ``build/extension_src/`` with the wheels, and writes a build copy of
   ``blender_manifest.toml`` there that lists the ``wheels`` and ``platforms``
   (the tracked manifest is never modified, so the repo stays clean).
3. runs Blender's own extension builder (``bl_pkg/cli/blender_ext.py build
   --split-platforms``) from the installed ``bpy`` package.

Prints the path of every zip built, one per line, after "built:".
"""
from __future__ import annotations

import argparse
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


def download_wheels(platform: str, python: str, requirements: list[str],
                    optional: set[str] = frozenset()) -> tuple[list[Path], list[str]]:
    """Wheels for ``platform`` and ``python`` in WHEEL_CACHE/<platform>/cp3xx/, downloading only what is not cached.

    Returns ``(wheels, missing)``: ``missing`` lists the requirements in ``optional`` (by name)
    that have no wheel for this platform and Python; any other missing wheel stops the build.
    """
    folder = WHEEL_CACHE / platform / _wheel_tag(python)
    folder.mkdir(parents=True, exist_ok=True)
    index_path = folder / "index.json"
    index = json.loads(index_path.read_text()) if index_path.exists() else {}
    wheels, missing = [], []
    tags = ",".join(PLATFORM_TAGS[platform])
    for req in requirements:
        key = f"{req} {tags}"  # a change of platform tags downloads again
        cached = index.get(key)
        if cached and (folder / cached).exists():
            wheels.append(folder / cached)
            continue
        name = req.split("==")[0].lower()
        if cached == "" and name in optional:  # known to have no wheel here
            missing.append(req)
            continue
        before = set(folder.glob("*.whl"))
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
               "--only-binary=:all:", "--no-deps", "--python-version", python,
               "--implementation", "cp", "--dest", str(folder)]
        for tag in PLATFORM_TAGS[platform]:
            cmd += ["--platform", tag]
        cmd.append(req)
        print(f"[{platform} {_wheel_tag(python)}] pip download {req}", flush=True)
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode:
            if name in optional and "No matching distribution" in result.stderr:
                index[key] = ""
                index_path.write_text(json.dumps(index, indent=1, sort_keys=True))
                missing.append(req)
                continue
            raise SystemExit(f"pip download {req} for {platform} / Python {python} failed:\n"
                             f"{result.stderr.strip()}")
        stem = name.replace("-", "_")
        new = sorted(set(folder.glob("*.whl")) - before) or sorted(
            p for p in folder.glob("*.whl") if p.name.lower().startswith(stem + "-"))
        if not new:
            raise SystemExit(f"pip download {req} for {platform} / Python {python}: no wheel found in {folder}")
        index[key] = new[0].name
        index_path.write_text(json.dumps(index, indent=1, sort_keys=True))
        wheels.append(new[0])
    return wheels, missing


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
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".*")
    for name in SHIPPED_SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, stage / name, ignore=ignore)
        elif src.is_file():
            shutil.copy2(src, stage / name)


def build(platforms: list[str], output_dir: Path, pythons: tuple[str, ...] = PYTHON_VERSIONS) -> list[Path]:
    stage = BUILD / "extension_src"
    stage_sources(stage)
    (stage / "wheels").mkdir()
    names = set()
    for platform in platforms:
        for python in pythons:
            wheels, missing = download_wheels(platform, python, shipped_requirements(python),
                                              optional=set(DECODER_REQUIREMENTS))
            for req in missing:
                print(f"WARNING: no wheel of {req} for {platform} / Python {python}: "
                      "that decoder is missing from this zip there", flush=True)
            for wheel in wheels:
                if wheel.name not in names:  # pure-Python wheels serve both Pythons
                    shutil.copy2(wheel, stage / "wheels" / wheel.name)
                    names.add(wheel.name)
    manifest = (ROOT / "blender_manifest.toml").read_text()
    (stage / "blender_manifest.toml").write_text(manifest_with_wheels(manifest, sorted(names), platforms))

    output_dir.mkdir(parents=True, exist_ok=True)
    before = {p: p.stat().st_mtime for p in output_dir.glob("*.zip")}
    cmd = [sys.executable, str(blender_ext_script()), "build", "--source-dir", str(stage),
           "--output-dir", str(output_dir), "--split-platforms"]
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode:
        raise SystemExit(f"Blender's extension builder failed:\n{result.stdout}\n{result.stderr}")
    zips = sorted(p for p in output_dir.glob("*.zip") if before.get(p) != p.stat().st_mtime)
    if len(zips) != len(platforms):
        raise SystemExit(f"expected {len(platforms)} zip(s), the builder wrote {zips}:\n{result.stdout}")
    return zips


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS),
                        help="build only this platform (repeatable); default: all four")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist",
                        help="folder for the zips (created if missing); default: dist/")
    args = parser.parse_args(argv)
    platforms = args.platform or list(PLATFORM_TAGS)
    zips = build(platforms, args.output_dir.resolve())
    print("built:")
    for z in zips:
        print(z)
    return 0


if __name__ == "__main__":
    sys.exit(main())
