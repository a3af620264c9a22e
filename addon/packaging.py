"""Build the installable extension zips with Blender's own extension tool (``make extension``).

Run from the repository root with the project's Python (no Blender needed; the
``bl_pkg`` command-line tool shipped inside the ``bpy`` module does the work)::

    python -m addon.packaging                # one zip per platform, wheels bundled, in dist/
    python -m addon.packaging --no-wheels    # one platform-independent zip, no wheels
    python -m addon.packaging --validate     # only run Blender's manifest validator

Steps:

1. Download (once, cached in ``build/wheels/``; never committed) the scipy and
   opencv-python-headless wheels for every platform Blender supports
   (linux-x64, windows-x64, macos-arm64, macos-x64), for Python 3.11 (Blender 4.2-5.0,
   numpy 1.26) and Python 3.13 (Blender 5.1+, numpy 2).  numpy is not bundled:
   Blender ships it.  opencv-python-headless 4.10 is an ``abi3`` wheel, one file per
   platform for both Pythons.
2. Stage ``blender_manifest.toml``, ``__init__.py``, ``addon/`` and ``core/`` into
   ``build/extension/``, adding ``platforms`` and ``wheels`` to the staged manifest
   (the committed manifest lists none, so it validates in a fresh clone).
3. ``blender_ext.py build --split-platforms`` writes
   ``dist/somacap-<version>-<platform>.zip``.  Blender installs only the wheels that
   match its platform and Python version.
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: Blender platform -> pip ``--platform`` tags (pip also accepts older compatible tags).
PLATFORMS = {
    "linux-x64": ["manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "windows-x64": ["win_amd64"],
    "macos-arm64": ["macosx_12_0_arm64"],
    "macos-x64": ["macosx_12_0_x86_64"],
}

#: Python version of the Blender series -> pinned requirements (numpy is Blender's).
REQUIREMENTS = {
    "3.11": ["scipy==1.14.1", "opencv-python-headless==4.10.0.84"],
    "3.13": ["scipy==1.15.3", "opencv-python-headless==4.10.0.84"],
}

#: What goes into the extension besides the manifest (the rest of the repo is dev-only).
PACKAGE_PATHS = ("__init__.py", "addon", "core")


def blender_ext_cli() -> Path:
    """Path of Blender's extension command-line tool inside the installed ``bpy`` module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("the bpy module is not installed in this Python environment")
    root = Path(list(spec.submodule_search_locations)[0])
    found = sorted(root.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"Blender's extension tool not found under {root}")
    return found[-1]


def run_blender_ext(*args: str) -> subprocess.CompletedProcess:
    """Run ``blender_ext.py`` with this interpreter; returns the completed process."""
    return subprocess.run(
        [sys.executable, str(blender_ext_cli()), *args], capture_output=True, text=True, check=False
    )


def validate(source: Path = REPO) -> subprocess.CompletedProcess:
    """Blender's ``validate`` on a source folder or a built zip."""
    return run_blender_ext("validate", str(source))


def download_wheels(cache: Path) -> list[Path]:
    """Download the bundled wheels into ``cache`` (reused when present); sorted paths."""
    wheels: dict[str, Path] = {}
    for py, reqs in REQUIREMENTS.items():
        for platform, tags in PLATFORMS.items():
            dest = cache / f"{platform}-py{py}"
            have = sorted(dest.glob("*.whl"))
            if len(have) < len(reqs):
                cmd = [
                    sys.executable,
                    "-m",
                    "pip",
                    "download",
                    "--quiet",
                    "--no-deps",
                    "--only-binary=:all:",
                    "--python-version",
                    py,
                    "-d",
                    str(dest),
                ]
                for tag in tags:
                    cmd += ["--platform", tag]
                subprocess.run(cmd + reqs, check=True)
                have = sorted(dest.glob("*.whl"))
            for whl in have:
                wheels.setdefault(whl.name, whl)  # abi3 wheels serve both Pythons
    return sorted(wheels.values(), key=lambda p: p.name)


def stage(dest: Path, wheels: list[Path]) -> Path:
    """Copy the package into ``dest`` and write its manifest with wheels and platforms."""
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "packaging.py")
    for rel in PACKAGE_PATHS:
        src = REPO / rel
        if src.is_dir():
            shutil.copytree(src, dest / rel, ignore=ignore)
        else:
            shutil.copy2(src, dest / rel)
    manifest = (REPO / "blender_manifest.toml").read_text(encoding="utf-8")
    if wheels:
        (dest / "wheels").mkdir()
        for whl in wheels:
            shutil.copy2(whl, dest / "wheels" / whl.name)
        listing = ",\n".join(f'  "./wheels/{w.name}"' for w in wheels)
        platforms = ", ".join(f'"{p}"' for p in PLATFORMS)
        extra = f"platforms = [{platforms}]\nwheels = [\n{listing},\n]\n\n"
        # Top-level keys must come before the first [table] of the TOML file.
        head, sep, tail = manifest.partition("\n[")
        manifest = head + "\n\n" + extra + sep.lstrip("\n") + tail if sep else manifest + extra
    (dest / "blender_manifest.toml").write_text(manifest, encoding="utf-8")
    tomllib.loads(manifest)  # fail here, not inside Blender's tool, on a broken edit
    return dest


def build(
    out_dir: Path, with_wheels: bool = True, cache: Path | None = None, staging: Path | None = None
) -> list[Path]:
    """Build the extension zip(s) into ``out_dir``; returns their paths.

    With wheels: one zip per platform (``--split-platforms``).  Without: a single
    platform-independent zip (for tests, where the environment already has scipy/cv2).
    """
    cache = cache or REPO / "build" / "wheels"
    staging = staging or REPO / "build" / "extension"
    wheels = download_wheels(cache) if with_wheels else []
    src = stage(staging, wheels)
    out_dir.mkdir(parents=True, exist_ok=True)
    version = tomllib.loads((src / "blender_manifest.toml").read_text())["version"]
    for old in out_dir.glob(f"somacap-{version}*.zip"):
        old.unlink()
    args = ["build", "--source-dir", str(src), "--output-dir", str(out_dir)]
    if wheels:
        args.append("--split-platforms")
    proc = run_blender_ext(*args)
    if proc.returncode != 0:
        raise SystemExit(f"blender_ext build failed:\n{proc.stdout}\n{proc.stderr}")
    return sorted(out_dir.glob(f"somacap-{version}*.zip"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m addon.packaging", description=__doc__)
    parser.add_argument("--out", type=Path, default=REPO / "dist", help="output folder")
    parser.add_argument("--no-wheels", action="store_true", help="skip the bundled wheels")
    parser.add_argument("--validate", action="store_true", help="only validate the manifest")
    args = parser.parse_args(argv)
    if args.validate:
        proc = validate()
        print(proc.stdout.strip(), proc.stderr.strip(), sep="\n")
        return proc.returncode
    for zip_path in build(args.out, with_wheels=not args.no_wheels):
        print(f"{zip_path}  {zip_path.stat().st_size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
