"""The service's solver, now :mod:`robocal.kinematics.ik` (one Newton for the library): kept importable here."""

from robocal.kinematics.ik import (
    CompiledChain,
    JointOffset,
    Solution,
    _rotvec,
    compile_chain,
    forward,
    quaternions,
    rotation_error,
    solve,
)

__all__ = [
    "CompiledChain",
    "JointOffset",
    "Solution",
    "_rotvec",
    "compile_chain",
    "forward",
    "quaternions",
    "rotation_error",
    "solve",
]
