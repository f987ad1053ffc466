"""Project exceptions. Every error names the thing that is wrong: file, row, column or parameter."""

from __future__ import annotations

import os


class RobocalError(Exception):
    """Base class of every error raised on purpose by robocal."""


class ConfigError(RobocalError, ValueError):
    """A configuration value or robot description is invalid; the message names the key."""


class DataError(RobocalError, ValueError):
    """A measurement file breaks the data contract.

    The message always names the file, and the row and column when the problem has one. Rows are
    counted as a text editor or spreadsheet shows them: the header is row 1, the first data row is row 2.
    """

    def __init__(
        self,
        message: str,
        *,
        file: str | os.PathLike[str] | None = None,
        row: int | None = None,
        column: str | None = None,
    ) -> None:
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        self.reason = message
        where = []
        if file is not None:
            where.append(f"file {self.file}")
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column {column!r}")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)
