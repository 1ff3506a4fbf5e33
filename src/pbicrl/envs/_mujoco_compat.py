"""Compatibility shim: gymnasium-robotics Fetch environments under mujoco >= 3.12.

gymnasium-robotics (<= 1.4.2) reads a joint's type with ``model.jnt_type[j]`` (a NumPy
integer) and checks it with ``joint_type in (mjtJoint.mjJNT_HINGE, mjtJoint.mjJNT_SLIDE)``.
Newer mujoco bindings make the enum's ``__eq__`` return ``False`` against NumPy integers
(the comparison is no longer symmetric), so that membership test fails and
``gym.make("FetchReach-v4")`` dies with a bare ``AssertionError`` inside
``set_joint_qpos``.  :func:`patch_gymnasium_robotics` replaces the four joint helpers of
``gymnasium_robotics.utils.mujoco_utils`` with versions that compare plain ``int``s; the
behaviour is otherwise identical.  It is applied only when the bug is detected and is
idempotent, so it is a no-op on fixed versions.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["needs_joint_type_patch", "original_joint_helpers", "patch_gymnasium_robotics"]

_PATCHED_FLAG = "_pbicrl_joint_type_patch"
_HELPERS = ("set_joint_qpos", "set_joint_qvel", "get_joint_qpos", "get_joint_qvel")
_ORIGINALS: dict[str, Any] = {}


def needs_joint_type_patch() -> bool:
    """Whether the installed mujoco breaks gymnasium-robotics' joint-type check.

    Returns
    -------
    bool
        True when ``np.int32(mjJNT_SLIDE) in (mjJNT_HINGE, mjJNT_SLIDE)`` is False.
    """
    import mujoco

    slide = mujoco.mjtJoint.mjJNT_SLIDE
    return np.int32(int(slide)) not in (mujoco.mjtJoint.mjJNT_HINGE, slide)


def _joint_width(model: Any, joint_id: int, *, velocity: bool) -> int:
    import mujoco

    jtype = int(model.jnt_type[joint_id])
    if jtype == int(mujoco.mjtJoint.mjJNT_FREE):
        return 6 if velocity else 7
    if jtype == int(mujoco.mjtJoint.mjJNT_BALL):
        return 3 if velocity else 4
    if jtype not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
        raise ValueError(f"joint {joint_id}: unsupported joint type {jtype}")
    return 1


def _joint_slice(model: Any, name: str, *, velocity: bool) -> slice:
    import mujoco

    joint_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
    if joint_id == -1:
        raise ValueError(f"Joint with name '{name}' is not part of the model!")
    start = int(model.jnt_dofadr[joint_id] if velocity else model.jnt_qposadr[joint_id])
    return slice(start, start + _joint_width(model, joint_id, velocity=velocity))


def _setter(velocity: bool):
    def set_joint(model: Any, data: Any, name: str, value: Any) -> None:
        sl = _joint_slice(model, name, velocity=velocity)
        value = np.asarray(value, dtype=np.float64)
        width = sl.stop - sl.start
        if width > 1 and value.shape != (width,):
            raise ValueError(f"Value has incorrect shape {name}: {value}")
        (data.qvel if velocity else data.qpos)[sl] = value

    return set_joint


def _getter(velocity: bool):
    def get_joint(model: Any, data: Any, name: str) -> np.ndarray:
        sl = _joint_slice(model, name, velocity=velocity)
        return (data.qvel if velocity else data.qpos)[sl].copy()

    return get_joint


def patch_gymnasium_robotics(force: bool = False) -> bool:
    """Patch gymnasium-robotics' joint helpers if (and only if) mujoco needs it.

    Parameters
    ----------
    force : bool
        Apply the patch even if the bug is not detected (used by tests).

    Returns
    -------
    bool
        True if the helpers are patched after the call (now or earlier).
    """
    from gymnasium_robotics.utils import mujoco_utils

    if getattr(mujoco_utils, _PATCHED_FLAG, False):
        return True
    if not (force or needs_joint_type_patch()):
        return False
    for name in _HELPERS:
        _ORIGINALS[name] = getattr(mujoco_utils, name)
    mujoco_utils.set_joint_qpos = _setter(velocity=False)
    mujoco_utils.set_joint_qvel = _setter(velocity=True)
    mujoco_utils.get_joint_qpos = _getter(velocity=False)
    mujoco_utils.get_joint_qvel = _getter(velocity=True)
    setattr(mujoco_utils, _PATCHED_FLAG, True)
    return True


def original_joint_helpers() -> dict[str, Any]:
    """The gymnasium-robotics helpers replaced by :func:`patch_gymnasium_robotics` (empty if unpatched)."""
    return dict(_ORIGINALS)
