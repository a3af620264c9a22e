"""Somacap core: the bpy-free numerical pipeline.

Stages (one module each): ``camera`` (projection model), ``calibration_io``
(calibration files), ``scene`` (scene folders), then calibration, matching,
surface, tracking, silhouettes, body model, fitting, ``state`` (the fitted-state
file) and ``evaluate`` (metrics against truth).  Nothing here imports ``bpy``.
"""

__version__ = "0.1.0"
