"""The add-on's one door into ``core``.

``core`` is found in two places:

* inside the installed extension (``bl_ext.<repo>.somacap``) it is the sibling
  sub-package ``bl_ext.<repo>.somacap.core``, reached by a relative import;
* in a checkout (tests, ``python -m addon.launch``) the repository root is on
  ``sys.path`` and ``addon`` is a top-level package, so ``core`` is top-level too.

Use ``from . import _core`` and then ``_core.camera.Camera`` etc.: sub-modules of core
are imported on first attribute access (PEP 562), so a stage that is not written yet
never breaks the add-on's registration.
"""

from __future__ import annotations

import importlib

try:  # installed extension: bl_ext.<repo>.somacap.core
    from .. import core
except ImportError:  # repository root on sys.path
    import core

__all__ = ["core", "load"]


def load(name: str):
    """Import and return ``core.<name>`` (works in both layouts)."""
    return importlib.import_module(f"{core.__name__}.{name}")


def __getattr__(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    try:
        return load(name)
    except ModuleNotFoundError as exc:
        if exc.name == f"{core.__name__}.{name}":
            raise AttributeError(f"core has no module {name!r}") from exc
        raise
