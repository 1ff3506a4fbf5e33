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

MuJoCo's default warning handler prints every warning and appends it to ``MUJOCO_LOG.TXT`` in the
*working directory*; mujoco >= 3.4 also warns that the ``settotalmass`` compiler attribute of Gymnasium's
HalfCheetah model is deprecated, once for every environment built. :func:`quiet_mujoco_warnings` installs a
handler that drops that one known message and passes every other warning on through Python's
:mod:`warnings` (category :class:`MujocoWarning`, so it can be filtered), so no log file appears in the
user's directory. It leaves a handler that someone else installed alone.
"""

from __future__ import annotations

import sys
import warnings
from typing import Any

import numpy as np

__all__ = ["needs_joint_type_patch", "original_joint_helpers", "patch_gymnasium_robotics", "quiet_mujoco_warnings",
           "MujocoWarning", "KNOWN_HARMLESS"]

KNOWN_HARMLESS: tuple[str, ...] = (
    # Gymnasium's half_cheetah.xml sets it; MuJoCo still applies it, and the model is not ours to change.
    "compiler attribute 'settotalmass' is deprecated",
)
"""Substrings of MuJoCo warnings that :func:`quiet_mujoco_warnings` drops."""


class MujocoWarning(RuntimeWarning):
    """A warning from the MuJoCo engine, passed on by :func:`quiet_mujoco_warnings`."""


def _mujoco_warning(message: str) -> None:
    text = str(message).strip()
    if any(known in text for known in KNOWN_HARMLESS):
        return
    try:
        warnings.warn(f"MuJoCo: {text}", MujocoWarning, stacklevel=2)
    except Exception:  # called from C: a warnings filter set to "error" must not raise through MuJoCo
        print(f"MuJoCo warning: {text}", file=sys.stderr)


def quiet_mujoco_warnings() -> bool:
    """Route MuJoCo's warnings through Python (no ``MUJOCO_LOG.TXT``) and drop :data:`KNOWN_HARMLESS` ones.

    Idempotent; a no-op without mujoco, or when another warning handler is installed already.

    Returns
    -------
    bool
        True if pbicrl's handler is installed after the call.
    """
    try:
        import mujoco
    except ImportError:
        return False
    try:
        current = mujoco.get_mju_user_warning()
        if current is _mujoco_warning:
            return True
        if current is not None:
            return False  # the user's (or another library's) handler: theirs to decide
        mujoco.set_mju_user_warning(_mujoco_warning)
    except (AttributeError, TypeError):  # a binding without warning callbacks
        return False
    return True

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

    quiet_mujoco_warnings()  # building environments comes next
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
