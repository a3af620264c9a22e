"""Run the Blender-side commands with the ``bpy`` module of the project's environment.

From the repository root::

    .venv/bin/python -m addon.launch fit SCENE --out take.blend [--target character.blend]
    .venv/bin/python -m addon.launch retarget fit.json --target character.blend --out take.blend
    .venv/bin/python -m addon.launch batch TAKES_DIR --out OUT_DIR

Identical to ``blender -c somacap …`` (see :mod:`addon.cli_command`): the add-on code is
imported from the checkout instead of an installed extension.  Exit status: 0 success,
1 some batch takes failed, 2 bad input.
"""

from __future__ import annotations

import os
import sys


def main(argv: list[str] | None = None) -> int:
    import bpy  # noqa: F401  (Blender as a Python module; fails clearly when missing)

    from .cli_command import main as cli_main

    return cli_main(sys.argv[1:] if argv is None else argv)


def _exit(code: int) -> None:
    """Exit with ``code``; the bpy 4.2 module crashes (SIGSEGV) at interpreter exit once
    Rigify has been enabled, so there the process leaves without finalising Python."""
    import bpy

    if bpy.app.version < (4, 3, 0):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    _exit(main())
