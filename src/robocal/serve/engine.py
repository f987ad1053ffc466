"""The service's solver, now :mod:`robocal.kinematics.ik` (one Newton for the library): kept importable here."""

from robocal.kinematics.ik import (
    CompiledChain,
    JointOffset,
    Solution,
    compile_chain,
    forward,
    quaternions,
    rotation_error,
    rotvec,
    solve,
)

__all__ = [
    "CompiledChain",
    "JointOffset",
    "Solution",
    "compile_chain",
    "forward",
    "quaternions",
    "rotation_error",
    "rotvec",
    "solve",
]
