"""CSV as spreadsheets write it: the delimiter and the decimal mark of a campaign file, found from the file itself.

Excel in most of Europe saves "CSV" with semicolons between the columns and decimal commas (``1523,4``), and
often in the Windows code page rather than UTF-8; a tab-separated export is common too. The data door reads such a
file as it reads a comma-separated one, and says so when a file cannot be read one way only:

* **delimiter**: the header row is split at ``,``, ``;`` and tab (quotes respected); the one that splits it into
  more than one column is the file's. A header that splits at two of them is an error naming both.
* **decimal mark** (semicolon- or tab-separated files): in the columns that may hold numbers (every column
  but the contract's text and time columns), a cell like ``1523,4`` or ``-0,25`` (``1.523,4`` with a thousands
  point) has a decimal comma, a cell like ``1523.4`` a decimal point. A file with decimal commas only is read
  with them (only cells that are such numbers are converted to decimal points, so an error still quotes a bad
  cell as written); a file with both is an error naming the first cell of each (``1.234`` is a thousands point
  or a decimal point: there is no telling). A comma-separated file keeps its cells as written.
* **encoding**: UTF-8 (with or without the byte order mark Excel writes), else Windows-1252, else Latin-1.

Integers are the same in both conventions, so a file without any decimal cell is read as it is.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from robocal.data.columns import POSE_COLUMNS
from robocal.errors import DataError

#: the delimiters a campaign file may use, with the word an error uses for each
DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}
#: columns that never hold numbers (their cells are never converted)
TEXT_COLUMNS = frozenset(c for g in POSE_COLUMNS if g.kind in ("text", "time") for c in g.names)
_EXP = r"(?:[eE][+-]?\d+)?"
#: a number with a decimal comma: ``1523,4``, ``-0,25``, ``,5``, ``1,5E-03``, or with thousands points ``1.523,4``
DECIMAL_COMMA = re.compile(rf"^\s*[+-]?(?:\d{{1,3}}(?:\.\d{{3}})+,\d*|\d+,\d*|,\d+){_EXP}\s*$")
#: a number with a decimal point: ``1523.4``, ``-.25``, ``1.5e-3`` (``1.234`` included: it may be a thousands point)
DECIMAL_POINT = re.compile(rf"^\s*[+-]?(?:\d+\.\d*|\.\d+){_EXP}\s*$")
FIX = (
    "save it with one convention: comma-separated with decimal points (Excel: 'CSV UTF-8'), or semicolon-"
    "separated with decimal commas throughout"
)


def decode(path: Path) -> str:
    """The file's text: UTF-8 (a byte order mark dropped), else Windows-1252 (Excel's 'CSV' on Windows), else
    Latin-1 (which decodes any byte)."""
    raw = path.read_bytes()
    for encoding in ("utf-8-sig", "cp1252"):
        try:
            return raw.decode(encoding)
        except UnicodeDecodeError:
            pass
    return raw.decode("latin-1")


def delimiter(header: str, path: Path) -> str:
    """The delimiter that splits the header row ``header`` into columns (``,`` for a one-column file)."""
    splits = {d: len(next(csv.reader([header], delimiter=d), [])) for d in DELIMITERS}
    found = [d for d, n in splits.items() if n > 1]
    if len(found) > 1:
        words = " and ".join(f"{DELIMITERS[d]}s ({splits[d]} columns)" for d in found)
        raise DataError(f"the header row has both {words}: which one separates the columns is ambiguous; {FIX}",
                        file=path, row=1)  # fmt: skip
    return found[0] if found else ","


def read_csv(path: Path) -> pd.DataFrame:
    """The CSV file ``path`` as text cells (every cell a string, nothing coerced), its delimiter and decimal mark
    found from the file (module docstring); the header as written (a repeated name is not renamed)."""
    text = decode(path)
    first = text.split("\n", 1)[0].rstrip("\r")
    sep = delimiter(first, path)
    kw = {"sep": sep, "dtype": str, "keep_default_na": False, "skipinitialspace": True}
    df = pd.read_csv(io.StringIO(text), **kw)  # type: ignore[call-overload]
    # pandas renames a repeated header ("x_mm", "x_mm.1"): keep the header as written, for the duplicate check
    header = pd.read_csv(io.StringIO(text), header=None, nrows=1, **kw)  # type: ignore[call-overload]
    df.columns = header.iloc[0].tolist()
    # a decimal comma needs another delimiter (Excel writes ';' wherever the decimal mark is ','); in a
    # comma-separated file a quoted "1,523" may be a thousands comma, so its cells are left as written
    return df if sep == "," else decimal_points(df, path)


def _matches(cells: pd.Series, pattern: re.Pattern[str]) -> np.ndarray:
    """Which text cells match ``pattern`` (Arrow's compiled regular expressions: a Python ``re`` per cell takes
    seconds on a 12 000-row campaign)."""
    arr = pa.array(cells.to_numpy(dtype=object), type=pa.string())
    return np.asarray(pc.match_substring_regex(arr, pattern.pattern).to_numpy(zero_copy_only=False), dtype=bool)


def decimal_points(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """``df`` with its decimal commas as decimal points when the file uses decimal commas only; an error naming
    the first cell of each kind when it mixes them; ``df`` itself when it has none."""
    first_comma: tuple[int, str] | None = None
    first_point: tuple[int, str] | None = None
    comma_cols: list[int] = []
    for k, col in enumerate(df.columns):
        if str(col).strip() in TEXT_COLUMNS:
            continue
        txt = df.iloc[:, k].astype(str)
        comma, point = _matches(txt, DECIMAL_COMMA), _matches(txt, DECIMAL_POINT)
        if comma.any():
            comma_cols.append(k)
            i = int(comma.argmax())
            if first_comma is None or i < first_comma[0]:
                first_comma = (i, str(col))
        if point.any():
            i = int(point.argmax())
            if first_point is None or i < first_point[0]:
                first_point = (i, str(col))
    if first_comma is None:
        return df
    if first_point is not None:
        (ic, cc), (ip, cp) = first_comma, first_point
        col_c, col_p = list(df.columns).index(cc), list(df.columns).index(cp)
        raise DataError(
            f"mixes decimal commas (row {ic + 2}, column {cc!r}: {df.iloc[ic, col_c]!r}) and decimal points "
            f"(row {ip + 2}, column {cp!r}: {df.iloc[ip, col_p]!r}); {FIX}",
            file=path,
            row=ip + 2 if ip > ic else ic + 2,
            column=cp if ip > ic else cc,
        )
    out = df.copy()
    for k in comma_cols:
        cells = out.iloc[:, k].astype(str)
        # "1.523,4" -> "1523.4": the thousands points go, the decimal comma becomes a point
        arr = pa.array(cells.to_numpy(dtype=object), type=pa.string())
        point = pc.replace_substring(pc.replace_substring(arr, ".", ""), ",", ".").to_numpy(zero_copy_only=False)
        out.isetitem(k, np.where(_matches(cells, DECIMAL_COMMA), point, cells.to_numpy(dtype=object)))
    return out
