"""Bulk keyframing that works with Blender 4.2's and 5.0's action APIs.

Blender 4.4 introduced slotted actions and 5.0 removed ``Action.fcurves``: F-curves
live in a channelbag, ``action.layers[0].strips[0].channelbag(slot)``, reached through
``bpy_extras.anim_utils.action_ensure_channelbag_for_slot``.  Blender 4.2/4.3 keep
``Action.fcurves``.  Keys are written in bulk with ``keyframe_points.add`` and
``foreach_set`` (never one ``keyframe_insert`` per key).
"""

from __future__ import annotations

import numpy as np

_LINEAR = 1  # index of 'LINEAR' in the keyframe interpolation enum


def slotted() -> bool:
    """True when this Blender has slotted actions (4.4+)."""
    import bpy

    return hasattr(bpy.types, "ActionSlot")


def assign_new_action(obj, name: str):
    """Create a new action called ``name`` (Blender adds ``.001`` on a clash, so an
    existing action is never overwritten) and assign it to ``obj``."""
    import bpy

    action = bpy.data.actions.new(name)
    ad = obj.animation_data or obj.animation_data_create()
    ad.action = action
    if slotted() and ad.action_slot is None:
        slot = action.slots.new(id_type="OBJECT", name=obj.name)
        ad.action_slot = slot
    return action


def _channelbag(obj, action):
    from bpy_extras.anim_utils import action_ensure_channelbag_for_slot

    slot = obj.animation_data.action_slot
    if slot is None:
        slot = action.slots.new(id_type="OBJECT", name=obj.name)
        obj.animation_data.action_slot = slot
    return action_ensure_channelbag_for_slot(action, slot)


def fcurves(obj, action):
    """The F-curve collection of ``action`` as animating ``obj``."""
    return _channelbag(obj, action).fcurves if slotted() else action.fcurves


def new_fcurve(obj, action, data_path: str, index: int, group: str):
    """Add an F-curve to the action's channels for ``obj``, in the named group."""
    if not slotted():
        return action.fcurves.new(data_path, index=index, action_group=group)
    bag = _channelbag(obj, action)
    fc = bag.fcurves.new(data_path, index=index)
    grp = bag.groups.get(group) if hasattr(bag.groups, "get") else None
    if grp is None:
        grp = next((g for g in bag.groups if g.name == group), None) or bag.groups.new(group)
    fc.group = grp
    return fc


def write_keys(fc, frames: np.ndarray, values: np.ndarray) -> None:
    """Set keys ``(frames[i], values[i])`` on an empty F-curve in one go (linear)."""
    frames = np.asarray(frames, dtype=np.float32)
    values = np.asarray(values, dtype=np.float32)
    n = len(frames)
    kp = fc.keyframe_points
    kp.add(n)
    co = np.empty(2 * n, dtype=np.float32)
    co[0::2], co[1::2] = frames, values
    kp.foreach_set("co", co)
    kp.foreach_set("interpolation", np.full(n, _LINEAR, dtype=np.int32))
    fc.update()


def mark_keys(fc, which: np.ndarray, key_type: str = "BREAKDOWN") -> int:
    """Give the keys ``which`` (K,) int (indices into the F-curve's keys) the keyframe
    type ``key_type`` (the dope sheet draws them apart); returns K."""
    kp = fc.keyframe_points
    for i in np.asarray(which, dtype=int):
        kp[int(i)].type = key_type
    return len(which)


def key_channels(
    obj,
    action,
    channels: dict,
    frames: np.ndarray,
    marked: dict | None = None,
    key_type: str = "BREAKDOWN",
) -> int:
    """Key many channels at once.

    Parameters
    ----------
    channels : dict
        ``(data_path, group) -> values (F, k)``: one F-curve per column ``k``.
    frames : (F,) frame numbers.
    marked : dict, optional
        ``group -> (F,) bool``: the frames whose keys in that group get ``key_type``.

    Returns
    -------
    int : number of keys written.
    """
    n = 0
    marked = marked or {}
    for (path, group), values in channels.items():
        values = np.asarray(values).reshape(len(frames), -1)
        which = np.flatnonzero(marked[group]) if group in marked else ()
        for i in range(values.shape[1]):
            fc = new_fcurve(obj, action, path, i, group)
            write_keys(fc, frames, values[:, i])
            if len(which):
                mark_keys(fc, which, key_type)
            n += len(frames)
    return n
