"""core/ must never import Blender modules: import every core module in a fresh interpreter."""

import subprocess
import sys

from tests.conftest import REPO


def test_every_core_module_imports_without_bpy():
    code = (
        "import importlib, pkgutil, sys, core\n"
        "names = [m.name for m in pkgutil.walk_packages(core.__path__, 'core.')\n"
        "         if not m.name.endswith('__main__')]\n"
        "for n in names: importlib.import_module(n)\n"
        "bad = [m for m in ('bpy', 'mathutils', 'bpy_extras') if m in sys.modules]\n"
        "print(len(names), bad)\n"
        "sys.exit(1 if bad else 0)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert int(out.stdout.split()[0]) >= 5
