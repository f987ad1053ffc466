"""A campaign's table read and its cells checked: the file found, read as text (CSV) or Parquet, numbers,
timestamps and names parsed with a :class:`robocal.errors.DataError` that names the file, row and column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from robocal.data.columns import columns
from robocal.data.dialect import read_csv
from robocal.errors import DataError


def _find(folder: Path, stem: str, required: bool) -> Path | None:
    csv, pq = folder / f"{stem}.csv", folder / f"{stem}.parquet"
    if csv.is_file() and pq.is_file():
        raise DataError(f"both {csv.name} and {pq.name} exist; keep one so it is clear which is the data", file=folder)
    if pq.is_file():
        return pq
    if csv.is_file():
        return csv
    if required:
        raise DataError(f"no {stem}.csv or {stem}.parquet in the campaign folder", file=folder)
    return None


def _read_table(path: Path) -> pd.DataFrame:
    try:
        if path.suffix == ".parquet":
            df = pd.read_parquet(path)
        else:
            # everything as text first, so that a bad cell is reported rather than silently coerced; the
            # delimiter and the decimal mark as the file has them (a European spreadsheet's ';' and ',')
            df = read_csv(path)
    except DataError:
        raise
    except Exception as exc:
        raise DataError(f"cannot be read as a table: {exc}", file=path) from None
    df.columns = [str(c).strip() for c in df.columns]
    dup = sorted({c for c in df.columns if list(df.columns).count(c) > 1})
    if dup:
        raise DataError(f"duplicated column name(s) {dup}", file=path, row=1, column=dup[0])
    if path.suffix != ".parquet" and len(df):
        # rows of bare separators at the end (",,,,,", as a spreadsheet saves the rows it once formatted) are not
        # rows: they were refused as a missing pose_id
        filled = df.astype(str).apply(lambda c: ~c.str.strip().isin(["", "nan"])).any(axis=1)
        last = int(np.flatnonzero(filled.to_numpy())[-1]) + 1 if filled.any() else 0
        df = df.iloc[:last]
    if len(df) == 0:
        raise DataError("has a header but no rows", file=path)
    return df


def _row(i: int) -> int:
    """File row of data row i (header = row 1)."""
    return int(i) + 2


def _numeric(df: pd.DataFrame, col: str, path: Path, *, required: bool = True) -> np.ndarray:
    s = df[col]
    if s.dtype == object or pd.api.types.is_string_dtype(s):
        txt = s.astype(str).str.strip()
        empty = txt.isin(["", "nan", "NaN", "NA", "None"])
        vals = pd.to_numeric(txt.where(~empty, None), errors="coerce")
        bad = vals.isna() & ~empty
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise DataError(f"expected a number, got {s.iloc[i]!r}", file=path, row=_row(i), column=col)
        arr = vals.to_numpy(dtype=float)
    else:
        try:
            arr = s.to_numpy(dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"expected numbers, column has type {s.dtype}", file=path, column=col) from None
    if required:
        nan = ~np.isfinite(arr)
        if nan.any():
            i = int(np.flatnonzero(nan)[0])
            raise DataError(
                f"missing or non-finite value in a required column ({int(nan.sum())} row(s))",
                file=path,
                row=_row(i),
                column=col,
            )
    return arr


def _timestamps(df: pd.DataFrame, col: str, path: Path) -> pd.Series:
    raw = df[col]
    if pd.api.types.is_datetime64_any_dtype(raw):
        ts = pd.to_datetime(raw, utc=True)
    else:
        txt = raw.astype(str).str.strip()
        ts = pd.to_datetime(txt, utc=True, errors="coerce", format="ISO8601")
    bad = ts.isna().to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise DataError(
            f"expected an ISO 8601 timestamp (e.g. 2026-01-01T08:00:00Z), got {raw.iloc[i]!r}",
            file=path,
            row=_row(i),
            column=col,
        )
    return ts


def _require(df: pd.DataFrame, cols: list[str], path: Path) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise DataError(
            f"missing required column(s) {missing}; present: {list(df.columns)}", file=path, row=1, column=missing[0]
        )


def _optional_block(df: pd.DataFrame, key: str, n: int, path: Path) -> np.ndarray | None:
    """The per-joint group ``key`` (:data:`robocal.data.columns.COLUMN`), all ``n`` columns or None."""
    names = columns(key, n)
    present = [c for c in names if c in df.columns]
    if not present:
        return None
    if len(present) != n:
        missing = [c for c in names if c not in df.columns]
        raise DataError(
            f"has {present} but not {missing}: give all {n} joints or none", file=path, row=1, column=missing[0]
        )
    return np.column_stack([_numeric(df, c, path) for c in names])


def _names(df: pd.DataFrame, col: str, path: Path, what: str) -> np.ndarray:
    """A text column with a value in every row (``what`` is the error's word for a missing one)."""
    txt = df[col].astype(str).str.strip().to_numpy()
    empty = (txt == "") | (txt == "nan") | df[col].isna().to_numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise DataError(f"missing {what}", file=path, row=_row(i), column=col)
    return txt


def _first(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])
