"""Kinematics: the one serial chain (MD-H and POE compiled to elementary transforms), its numba kernels,
rotations and transforms on arrays, and static gravity torques. The bottom layer: imports nothing else of
robocal; importing it reads and writes nothing."""
