"""The columns of a campaign's ``poses`` file, declared once.

:data:`POSE_COLUMNS` is the data contract's table of columns, in the order a campaign is written: the data door
(:func:`robocal.data.contract.read_campaign`) takes the required and known columns from it, the twin
(:func:`robocal.sim.twin.simulate`) writes its header and number formats from it, and
:meth:`robocal.data.contract.Campaign.to_frame` orders its columns by it. A column added here is read, written and
copied everywhere.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

#: the placeholder of the (1-based) joint number in a per-joint column's name
JOINT = "{j}"


@dataclass(frozen=True)
class ColumnGroup:
    """One quantity of the contract: one column (``payload_kg``), a fixed set (``x_mm``, ``y_mm``, ``z_mm``) or
    one column per joint (a name with ``{j}``, e.g. ``q{j}_deg``).

    key : the quantity's name in the code; names : the column names (templates for a per-joint group);
    kind : ``text``, ``time``, ``number`` or ``sign`` (-1 / +1); required : every campaign has it;
    decimals : the twin's fixed number format (``None``: written as text, or as an integer for a sign).
    A group of several columns is given whole or not at all.
    """

    key: str
    names: tuple[str, ...]
    kind: str
    required: bool = False
    decimals: int | None = None

    @property
    def per_joint(self) -> bool:
        return JOINT in self.names[0]

    def columns(self, n_joints: int) -> list[str]:
        """The column names for a robot with ``n_joints`` joints."""
        if self.per_joint:
            return [self.names[0].format(j=j + 1) for j in range(n_joints)]
        return list(self.names)


#: the poses file's columns, in the contract's order (README, "Your own data"; docs/own-data.md)
POSE_COLUMNS: tuple[ColumnGroup, ...] = (
    ColumnGroup("pose_id", ("pose_id",), "text", required=True),
    ColumnGroup("timestamp", ("timestamp",), "time", required=True),
    ColumnGroup("target", ("target",), "text"),
    ColumnGroup("q", ("q{j}_deg",), "number", required=True, decimals=6),
    ColumnGroup("p", ("x_mm", "y_mm", "z_mm"), "number", required=True, decimals=6),
    ColumnGroup("quat", ("qw", "qx", "qy", "qz"), "number", decimals=9),
    ColumnGroup("payload", ("payload_kg",), "number", decimals=3),
    ColumnGroup("tau", ("tau{j}_Nm",), "number", decimals=6),
    ColumnGroup("current", ("i{j}_A",), "number", decimals=6),
    ColumnGroup("direction", ("dir{j}",), "sign"),
    ColumnGroup("split", ("split",), "text"),
    ColumnGroup("station", ("station",), "text"),
    ColumnGroup("u_mm", ("u_mm",), "number"),
)
#: the groups by key
COLUMN = {g.key: g for g in POSE_COLUMNS}
#: the per-joint signal groups the effects read and the twin reports (torque, current, approach direction)
JOINT_SIGNALS = ("tau", "current", "direction")
#: digits of a column the contract does not name (an extra column), as the twin writes it
EXTRA_DECIMALS = 6


def columns(key: str, n_joints: int = 0) -> list[str]:
    """The column names of the group ``key`` (``n_joints`` for a per-joint group)."""
    return COLUMN[key].columns(n_joints)


def column_name(key: str) -> str:
    """The one column name of a single-column group (``column_name("pose_id") == "pose_id"``)."""
    (col,) = COLUMN[key].names
    return col


def joint_columns(prismatic: Iterable[bool]) -> list[str]:
    """The joint value columns of a robot whose joints are prismatic where ``prismatic`` says: ``q<j>_mm`` for a
    prismatic joint (a length, mm), ``q<j>_deg`` for a revolute one."""
    return [f"q{j + 1}_mm" if s else COLUMN["q"].names[0].format(j=j + 1) for j, s in enumerate(prismatic)]


def _group_columns(g: ColumnGroup, n_joints: int, prismatic: Iterable[bool] | None) -> list[str]:
    if g.key == "q" and prismatic is not None:
        return joint_columns(prismatic)
    return g.columns(n_joints)


def required_columns(n_joints: int, prismatic: Iterable[bool] | None = None) -> list[str]:
    """Every required column, in the contract's order (``prismatic``: which joints are lengths, see
    :func:`joint_columns`; all revolute when None)."""
    return [c for g in POSE_COLUMNS if g.required for c in _group_columns(g, n_joints, prismatic)]


def known_columns(n_joints: int, prismatic: Iterable[bool] | None = None) -> set[str]:
    """Every column the contract names for a robot with ``n_joints`` joints (the rest are extra columns)."""
    return {c for g in POSE_COLUMNS for c in _group_columns(g, n_joints, prismatic)}
