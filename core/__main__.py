"""``python -m core``: the command line of the bpy-free pipeline (see :mod:`core.cli`)."""

import sys

from .cli import main

sys.exit(main())
