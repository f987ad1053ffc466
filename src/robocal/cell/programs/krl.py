"""KUKA KRL programs: read the targets of ``NAME.src`` + ``NAME.dat``, write them back corrected.

What is read
------------
* ``.dat``: ``[DECL] [GLOBAL] E6POS|POS|E6AXIS|AXIS|FRAME|FDAT name={...}`` declarations, and ``TOOL_DATA[n]=``
  / ``BASE_DATA[n]={...}`` assignments (also from a ``$config.dat`` in the program's folder, which is read, never
  written); aggregates may carry a type prefix (``{E6POS: X 1, ...}``); Status/Turn as integers or bit strings
  (``'B010'``).
* ``.src``: motions ``PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL`` to a declared name or an inline aggregate (``CIRC`` has
  two targets), ``$TOOL=`` / ``$BASE=`` (``TOOL_DATA[n]``, a FRAME name, an inline frame or ``$NULLFRAME``), and
  ``FDAT_ACT=name`` (the inline forms' tool and base numbers, ``TOOL_NO`` / ``BASE_NO``). ``;`` comments
  (including ``;FOLD`` / ``;ENDFOLD``), ``&`` header lines, mixed case and any other statement pass through.
  Tool and base start as ``$NULLFRAME`` (flange, robot base), as after a controller reset.

Refused, with the file and line: relative motions (``PTP_REL`` ...), the geometric operator (``XP1:{X 10}``),
system variables or expressions as targets (except ``$POS_ACT`` / ``$AXIS_ACT``, which are left alone), a
target assigned at run time (``XP1.X=...``), a target used with two different tools or bases, an unknown name,
an incomplete aggregate, an unknown aggregate key, external axes that move (E1..E6 are copied, never
corrected). Limits: one statement per line (KRL has no line continuation); ``DEF``/``DEFFCT`` structure,
``IF``/loops and subprogram calls are not followed: targets are taken in text order, tools and bases as
assigned above them in the text.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from robocal.cell.programs.common import (
    ProgramError,
    Target,
    abc_deg,
    blank_to_line_end,
    format_number,
    line_of,
    read_text,
    reuse_target,
    rot_zyx_deg,
)
from robocal.kinematics.transforms import homogeneous

POSE_TYPES = ("e6pos", "pos")
AXIS_TYPES = ("e6axis", "axis")
_POSE_KEYS = ("x", "y", "z", "a", "b", "c")
_EXT = tuple(f"e{i}" for i in range(1, 7))
_AXES = tuple(f"a{i}" for i in range(1, 7))

_DECL = re.compile(
    r"^[ \t]*(?:DECL[ \t]+)?(?:GLOBAL[ \t]+)?(?:DECL[ \t]+)?(E6POS|POS|E6AXIS|AXIS|FRAME|FDAT)[ \t]+(\w+)"
    r"[ \t]*=[ \t]*(\{)",
    re.IGNORECASE | re.MULTILINE,
)
_DATA = re.compile(r"^[ \t]*(TOOL_DATA|BASE_DATA)\[[ \t]*(\d+)[ \t]*\][ \t]*=[ \t]*(\{)", re.IGNORECASE | re.MULTILINE)
_MOTION = re.compile(r"^[ \t]*(PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL)(_REL)?\b[ \t]*(.*)$", re.IGNORECASE)
_ASSIGN_FRAME = re.compile(r"^[ \t]*\$(TOOL|BASE)[ \t]*=[ \t]*(.*?)[ \t]*$", re.IGNORECASE)
_FDAT_ACT = re.compile(r"^[ \t]*FDAT_ACT[ \t]*=[ \t]*(\w+)[ \t]*$", re.IGNORECASE)
_ASSIGN = re.compile(r"^[ \t]*(\w+)[ \t]*(?:\.[ \t]*\w+[ \t]*)?=", re.IGNORECASE)
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def _mask_comments(text: str) -> str:
    """``text`` with every ``;`` comment replaced by spaces (strings kept), same length, so offsets agree."""
    out = list(text)
    i, n = 0, len(text)
    in_str = False
    while i < n:
        ch = text[i]
        if ch == "\n":
            in_str = False
        elif in_str:
            if ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch == ";":
            i = blank_to_line_end(text, out, i)
            continue
        i += 1
    return "".join(out)


def _brace_end(code: str, start: int, file: Path, text: str) -> int:
    """Index just past the ``}`` closing the ``{`` at ``start`` (same line)."""
    depth = 0
    i = start
    while i < len(code):
        ch = code[i]
        if ch == "\n":
            break
        if ch == '"':
            j = code.find('"', i + 1)
            i = j if j >= 0 else len(code)
        elif ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
            if depth == 0:
                return i + 1
        i += 1
    raise ProgramError("unbalanced '{' in an aggregate (KRL has no line continuation)", file, line_of(text, start))


def parse_aggregate(s: str, file: Path, line: int) -> tuple[str | None, dict[str, str], list[str]]:
    """``{[TYPE:] K v, K v, ...}`` -> (type or None, {key lower: value text}, keys in order as written)."""
    body = s.strip()[1:-1]
    typ = None
    m = re.match(r"^\s*(\w+)\s*:", body)
    if m and not re.match(r"^\s*\w+\s*:\s*=", body):
        typ = m.group(1).lower()
        body = body[m.end() :]
    vals: dict[str, str] = {}
    order: list[str] = []
    for part in _split_top(body):
        part = part.strip()
        if not part:
            continue
        mm = re.match(r"^(\w+(?:\[\])?)\s+(.+)$", part, re.DOTALL)
        if not mm:
            raise ProgramError(f"cannot read the aggregate item {part!r}", file, line)
        k = mm.group(1).lower()
        vals[k] = mm.group(2).strip()
        order.append(mm.group(1))
    return typ, vals, order


def _split_top(s: str) -> list[str]:
    parts: list[str] = []
    cur: list[str] = []
    depth, in_str = 0, False
    for ch in s:
        if ch == '"':
            in_str = not in_str
        if not in_str:
            if ch in "{[(":
                depth += 1
            elif ch in "}])":
                depth -= 1
            elif ch == "," and depth == 0:
                parts.append("".join(cur))
                cur = []
                continue
        cur.append(ch)
    parts.append("".join(cur))
    return parts


def _number(v: str, key: str, file: Path, line: int) -> float:
    if not re.fullmatch(_NUM, v.strip()):
        raise ProgramError(f"{key.upper()} must be a number, got {v!r}", file, line)
    return float(v)


def _bits(v: str, key: str, file: Path, line: int) -> tuple[int, str]:
    v = v.strip()
    m = re.fullmatch(r"'B([01]+)'", v, re.IGNORECASE)
    if m:
        return int(m.group(1), 2), "bits"
    if re.fullmatch(r"[-+]?\d+", v):
        return int(v), "int"
    raise ProgramError(f"{key.upper()} must be an integer or a bit string 'B...', got {v!r}", file, line)


def _frame_of(vals: dict[str, str], file: Path, line: int, what: str) -> np.ndarray:
    missing = [k.upper() for k in _POSE_KEYS if k not in vals]
    if missing:
        raise ProgramError(f"{what} lacks {missing}; every target needs X, Y, Z, A, B, C", file, line)
    v = {k: _number(vals[k], k, file, line) for k in _POSE_KEYS}
    return homogeneous(rot_zyx_deg(v["a"], v["b"], v["c"]), np.array([v["x"], v["y"], v["z"]]))


class _Decl:
    def __init__(self, typ: str, name: str, file: Path, text: str, span: tuple[int, int], line: int) -> None:
        self.typ, self.name, self.file, self.text, self.span, self.line = typ, name, file, text, span, line
        self.atype, self.vals, self.order = parse_aggregate(text[span[0] : span[1]], file, line)


def _scan_dat(path: Path, text: str, decls: dict[str, _Decl], data: dict[tuple[str, int], _Decl]) -> None:
    code = _mask_comments(text)
    for m in _DECL.finditer(code):
        s = m.start(3)
        e = _brace_end(code, s, path, text)
        d = _Decl(m.group(1).lower(), m.group(2), path, text, (s, e), line_of(text, s))
        decls[m.group(2).lower()] = d
    for m in _DATA.finditer(code):
        s = m.start(3)
        e = _brace_end(code, s, path, text)
        d = _Decl("frame", f"{m.group(1)}[{m.group(2)}]", path, text, (s, e), line_of(text, s))
        data[(m.group(1).lower(), int(m.group(2)))] = d


def read_krl(src: str | Path) -> Any:
    """Read ``NAME.src`` (+ ``NAME.dat`` beside it, + ``$config.dat`` in the same folder if present)."""
    from robocal.cell.programs.common import Program

    src = Path(src)
    if src.suffix.lower() == ".dat":
        src = src.with_suffix(".src") if src.with_suffix(".src").exists() else src.with_suffix(".SRC")
    if not src.is_file():
        raise ProgramError("no such KRL program", src)
    dat = next((p for p in (src.with_suffix(".dat"), src.with_suffix(".DAT")) if p.is_file()), None)
    texts: dict[Path, str] = {src: read_text(src)}
    decls: dict[str, _Decl] = {}
    data: dict[tuple[str, int], _Decl] = {}
    cfg = next((p for p in src.parent.iterdir() if p.name.lower() == "$config.dat"), None)
    if cfg is not None:
        _scan_dat(cfg, read_text(cfg), decls, data)
    if dat is not None:
        texts[dat] = read_text(dat)
        _scan_dat(dat, texts[dat], decls, data)
    reader = _SrcReader(src, dat, texts[src], decls, data)
    reader.read()
    if not reader.order:
        raise ProgramError("no motion target found", src)
    return Program("krl", texts, reader.order, src)


class _SrcReader:
    """One pass over the ``.src``: the motion targets in order, each with the tool and base active where it is
    used (``$TOOL`` / ``$BASE`` assignments and ``FDAT_ACT``)."""

    def __init__(
        self, src: Path, dat: Path | None, text: str, decls: dict[str, _Decl], data: dict[tuple[str, int], _Decl]
    ) -> None:
        self.src, self.dat, self.text, self.decls, self.data = src, dat, text, decls, data
        self.code = _mask_comments(text)
        self.tool, self.base = np.eye(4), np.eye(4)
        self.tool_name, self.base_name = "$NULLFRAME", "$NULLFRAME"
        self.targets: dict[str, Target] = {}
        self.order: list[Target] = []
        self.target_names = {k for k, d in decls.items() if d.typ in POSE_TYPES + AXIS_TYPES}

    def read(self) -> None:
        pos = 0
        for raw_line in self.code.split("\n"):
            line_start = pos
            pos += len(raw_line) + 1
            stmt = raw_line.rstrip("\r")
            if not stmt.strip() or stmt.lstrip().startswith("&"):
                continue
            self.statement(stmt, line_start, line_of(self.text, line_start))

    def statement(self, stmt: str, line_start: int, line: int) -> None:
        """A motion (its targets), a ``$TOOL`` / ``$BASE`` assignment, an ``FDAT_ACT``, or a target assigned at
        run time (an error); anything else is left alone."""
        src = self.src
        m = _MOTION.match(stmt)
        if m:
            if m.group(2):
                raise ProgramError(f"relative motion {m.group(1).upper()}_REL cannot be filtered per target", src, line)
            rest_start = line_start + m.start(3)
            args = _motion_args(m.group(3), 2 if m.group(1).upper() in ("CIRC", "SCIRC") else 1, src, line)
            for a_off, a_text in args:
                if re.match(r"^\s*(\w+|\{[^}]*\})\s*:", a_text):
                    raise ProgramError("the geometric operator ':' on a target is not supported", src, line)
                self.add_target(a_text, rest_start + a_off, line)
            return
        m = _ASSIGN_FRAME.match(stmt)
        if m:
            which = m.group(1).upper()
            f, nm = self.resolve_frame(m.group(2), line, which)
            if which == "TOOL":
                self.tool, self.tool_name = f, nm
            else:
                self.base, self.base_name = f, nm
            return
        m = _FDAT_ACT.match(stmt)
        if m:
            d = self.decls.get(m.group(1).lower())
            if d is None or d.typ != "fdat":
                raise ProgramError(f"FDAT_ACT={m.group(1)}: no FDAT of that name", src, line)
            tn = int(_number(d.vals.get("tool_no", "0"), "tool_no", d.file, d.line))
            bn = int(_number(d.vals.get("base_no", "0"), "base_no", d.file, d.line))
            self.tool, self.tool_name = self.tool_base_no(tn, "TOOL", line)
            self.base, self.base_name = self.tool_base_no(bn, "BASE", line)
            return
        m = _ASSIGN.match(stmt)
        if m and m.group(1).lower() in self.target_names:
            raise ProgramError(
                f"target {m.group(1)!r} is assigned at run time; its value is not known before the run", src, line
            )

    def resolve_frame(self, expr: str, line: int, which: str) -> tuple[np.ndarray, str]:
        src, dat = self.src, self.dat
        e = expr.strip()
        if e.upper() == "$NULLFRAME":
            return np.eye(4), "$NULLFRAME"
        m = re.fullmatch(r"(TOOL_DATA|BASE_DATA)\[\s*(\d+)\s*\]", e, re.IGNORECASE)
        if m:
            key = (m.group(1).lower(), int(m.group(2)))
            d = self.data.get(key)
            if d is None:
                raise ProgramError(
                    f"{e} is not defined in {dat.name if dat else 'the .dat'} or a $config.dat beside the program",
                    src,
                    line,
                )
            return _frame_of(d.vals, d.file, d.line, e), e
        if e.startswith("{"):
            _, vals, _ = parse_aggregate(e, src, line)
            return _frame_of(vals, src, line, f"${which}"), e
        d = self.decls.get(e.lower())
        if d is not None and d.typ in ("frame", "pos", "e6pos"):
            return _frame_of(d.vals, d.file, d.line, e), e
        raise ProgramError(f"${which}={e}: cannot resolve {e!r} to a frame", src, line)

    def tool_base_no(self, no: int, kind: str, line: int) -> tuple[np.ndarray, str]:
        if no == 0:
            return np.eye(4), "$NULLFRAME"
        return self.resolve_frame(f"{kind}_DATA[{no}]", line, kind)

    def add_target(self, arg: str, arg_start: int, line: int) -> None:
        src, dat, text = self.src, self.dat, self.text
        a = arg.strip()
        if a.startswith("{"):
            s = arg_start + (len(arg) - len(arg.lstrip()))
            e = _brace_end(self.code, s, src, text)
            typ, vals, keys = parse_aggregate(text[s:e], src, line)
            kind = "axis" if any(k in vals for k in _AXES) else "pose"
            t = _make_target("<inline>", kind, src, text, (s, e), line, vals, keys, typ)
        else:
            name = a
            if not re.fullmatch(r"\w+", name):
                if name.upper() in ("$POS_ACT", "$AXIS_ACT"):
                    return
                raise ProgramError(f"target {name!r} is not a declared name or an aggregate", src, line)
            d = self.decls.get(name.lower())
            if d is None or d.typ not in POSE_TYPES + AXIS_TYPES:
                what = "not declared" if d is None else f"a {d.typ.upper()}, not a target"
                raise ProgramError(f"target {name!r} is {what} (looked in {dat.name if dat else 'no .dat'})", src, line)
            if d.file != dat:
                raise ProgramError(
                    f"target {name!r} is declared in {d.file.name}, which is not written; "
                    "declare it in the program's .dat",
                    src,
                    line,
                )
            key = name.lower()
            if reuse_target(self.targets, key, self.tool, self.base, f"{self.tool_name}/{self.base_name}", src, line):
                return
            kind = "pose" if d.typ in POSE_TYPES else "axis"
            t = _make_target(d.name, kind, d.file, d.text, d.span, d.line, d.vals, d.order, d.atype)
            self.targets[key] = t
        t.tool, t.base, t.tool_name, t.base_name = self.tool.copy(), self.base.copy(), self.tool_name, self.base_name
        t.used_at.append((str(src), line))
        self.order.append(t)


def _motion_args(rest: str, n: int, file: Path, line: int) -> list[tuple[int, str]]:
    """The first ``n`` target arguments of a motion (offsets into ``rest``)."""
    out = []
    i = 0
    for _ in range(n):
        while i < len(rest) and rest[i] in " \t,":
            i += 1
        if i >= len(rest):
            raise ProgramError("motion without a target", file, line)
        start = i
        if rest[i] == "{":
            depth = 0
            while i < len(rest):
                if rest[i] == "{":
                    depth += 1
                elif rest[i] == "}":
                    depth -= 1
                    if depth == 0:
                        i += 1
                        break
                i += 1
            else:
                raise ProgramError("unbalanced '{' in a motion", file, line)
        else:
            while i < len(rest) and rest[i] not in " \t,":
                i += 1
        tok = rest[start:i]
        # a ':' right after a name is the geometric operator
        j = i
        while j < len(rest) and rest[j] in " \t":
            j += 1
        if j < len(rest) and rest[j] == ":":
            tok = rest[start : j + 1]
        out.append((start, tok))
    return out


def _make_target(
    name: str,
    kind: str,
    file: Path,
    text: str,
    span: tuple[int, int],
    line: int,
    vals: dict[str, str],
    keys: list[str],
    typ: str | None,
) -> Target:
    known = set(_POSE_KEYS) | {"s", "t"} | set(_EXT) if kind == "pose" else set(_AXES) | set(_EXT)
    unknown = sorted(set(vals) - known)
    if unknown:
        raise ProgramError(f"target {name}: unknown aggregate key(s) {[u.upper() for u in unknown]}", file, line)
    t = Target(name=name, kind=kind, file=file, line=line, span=span)
    t.data = {"keys": keys, "vals": vals, "type": typ, "orig": text[span[0] : span[1]]}
    if kind == "pose":
        t.T_base_tcp = _frame_of(vals, file, line, f"target {name}")
        for k in ("s", "t"):
            if k in vals:
                v, style = _bits(vals[k], k, file, line)
                t.config[k.upper()] = v
                t.data[f"{k}_style"] = style
    else:
        missing = [a.upper() for a in _AXES if a not in vals]
        if missing:
            raise ProgramError(f"target {name} lacks {missing}", file, line)
        t.q_deg = np.array([_number(vals[a], a, file, line) for a in _AXES])
    return t


def render(t: Target, new: dict[str, Any]) -> str:
    """The target's aggregate with new values: ``new`` has ``T_base_tcp`` + ``S``/``T`` (pose) or ``q_deg``
    (axis). Keys keep their order and spelling; values not corrected (E1..E6) keep their text."""
    vals: dict[str, str] = dict(t.data["vals"])
    if t.kind == "pose":
        T = new["T_base_tcp"]
        # the representation nearest to the target's own A, B, C (a tool-down B = 90 keeps its A and C)
        a, b, c = abc_deg(T[:3, :3], near=(float(vals["a"]), float(vals["b"]), float(vals["c"])))
        for k, v in zip(_POSE_KEYS, [*T[:3, 3], a, b, c], strict=True):
            vals[k] = format_number(float(v), 4 if k in "xyz" else 5)
        for k in ("S", "T"):
            if k in new and k.lower() in vals:
                v = int(new[k])
                vals[k.lower()] = f"'B{v:b}'" if t.data.get(f"{k.lower()}_style") == "bits" else str(v)
    else:
        for k, v in zip(_AXES, new["q_deg"], strict=True):
            vals[k] = format_number(float(v), 5)
    orig: str = t.data["orig"]
    # keep the separators as written: rebuild item by item
    inner = orig[1:-1]
    prefix = ""
    m = re.match(r"^(\s*\w+\s*:)", inner)
    if t.data["type"] is not None and m:
        prefix = m.group(1)
        inner = inner[m.end() :]
    parts = _split_top(inner)
    out = []
    for part in parts:
        mm = re.match(r"^(\s*)(\w+(?:\[\])?)(\s+)(.*?)(\s*)$", part, re.DOTALL)
        if not mm:
            out.append(part)
            continue
        key = mm.group(2).lower()
        out.append(mm.group(1) + mm.group(2) + mm.group(3) + vals.get(key, mm.group(4)) + mm.group(5))
    return "{" + prefix + ",".join(out) + "}"
