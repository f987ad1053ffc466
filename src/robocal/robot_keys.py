"""The keys a robot description reads, and those it refuses (:func:`robocal.robot.robot_from_dict`): a misspelt key
or one other tools read with a meaning a description here does not have would otherwise be ignored silently."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from robocal.errors import ConfigError

#: the keys a robot description reads (top level, and per joint): a key one letter away from one of them is a
#: misspelling, refused (``beta_fre: true`` was ignored and the joint's beta held; ``conventon: dh`` read a DH table
#: as MD-H); any other key is the user's own (``source``, ``notes`` ...) and left alone
ROBOT_KEYS = ("name", "n_joints", "units", "convention", "joints", "poe", "coupling", "dynamics", "T0_C",
              "temperature_sensors", "signals", "positioner")  # fmt: skip
JOINT_KEYS = ("name", "type", "role", "a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "beta_deg", "beta_free",
              "q_min_deg", "q_max_deg", "q_min_mm", "q_max_mm")  # fmt: skip


#: where a robot mounted on a ceiling or a wall states it
MOUNTED = ("a robot mounted on a ceiling or a wall states gravity in its base frame: dynamics: {gravity_mps2: [0, 0, "
           "9.81]} (ceiling), e.g. [0, -9.81, 0] (wall)")  # fmt: skip

#: keys other tools read with a kinematic meaning a description here does not have, and why: refused, not left alone
#: as the user's own (a newcomer's ``sign: -1`` on a joint and a top-level ``tool:`` were ignored silently)
NOT_READ = {
    "joint": (("sign", "direction", "flip", "flipped", "reversed", "reverse", "invert", "inverted", "axis",
               "gear_ratio", "ratio", "offset"), "every joint turns about its own +z here: a joint counted the other "
              "way is given by its column's sign in poses.csv (negate it) or by a URDF with <axis xyz='0 0 -1'>; its "
              "zero is theta_offset_deg"),
    "robot": (("tool", "base", "tool_frame", "base_frame", "flange", "tcp", "world", "base_T", "tool_T"), "the "
              "tracker (base) frame and the tools are fitted from the measurements (the targets); a fixed base or "
              "tool frame belongs in a URDF given as FILE.urdf#BASE:TIP"),
    # a mounting stated where it is not read: the arm's weight then deflected it the floor's way (newcomer pass 15:
    # a wall-mounted arm's 'mounting: wall' ignored, 4.78 mm held out where gravity_mps2 gave 0.034)
    "mounting": (("mounting", "mount", "mounted", "installation", "gravity", "gravity_mps2", "g", "orientation"),
                 "the mounting is stated as gravity in the base frame, under dynamics (with or without link masses): "
                 "dynamics: {gravity_mps2: [0, 0, -9.81]} on a floor (the default), [0, 0, 9.81] on a ceiling, "
                 "e.g. [0, -9.81, 0] on a wall"),
}  # fmt: skip


def refuse_unknown_keys(keys: Any, known: Sequence[str], where: str, level: str = "robot") -> None:
    """Refuse a key of ``keys`` that is not in ``known`` but close to one of them (a misspelling), or one that other
    tools read with a meaning a description here does not have (:data:`NOT_READ`)."""
    from difflib import get_close_matches

    for k in keys:
        for lv in (level, "mounting") if level == "robot" else (level,):
            if isinstance(k, str) and k in NOT_READ[lv][0]:
                # a base given as a frame may be a mounting: where gravity is stated said too (not for a tool)
                more = f"; {MOUNTED}" if k in ("base", "base_frame", "base_T", "world") else ""
                raise ConfigError(
                    f"{where}: key {k!r} is not read by robocal and would be ignored: {NOT_READ[lv][1]}{more}"
                )
    for k in keys:
        if isinstance(k, str) and k not in known:
            if get_close_matches(k, known, n=1, cutoff=0.8):
                like = " or ".join(repr(c) for c in get_close_matches(k, known, n=2, cutoff=0.6))
                raise ConfigError(f"{where}: unknown key {k!r}: did you mean {like}? (a misspelt key would be ignored)")


__all__ = ["JOINT_KEYS", "NOT_READ", "ROBOT_KEYS"]
