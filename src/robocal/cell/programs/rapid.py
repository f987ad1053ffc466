"""ABB RAPID modules: read the targets of a ``.mod``, write them back corrected.

What is read
------------
* data declarations ``[LOCAL|TASK] CONST|PERS|VAR robtarget|jointtarget|tooldata|wobjdata name := value;``
  (a statement may span lines; ``!`` comments may sit anywhere between tokens);
* ``MoveL``, ``MoveJ``, ``MoveC`` (two targets) and ``MoveAbsJ`` with a declared name or an inline value,
  leading switches (``\\Conc``), optional arguments after each argument (``v100\\T:=2``, ``tool1\\WObj:=wobj1``);
  the tool is the positional argument after the zone, the work object ``\\WObj`` (default ``wobj0``);
  ``tool0`` / ``wobj0`` are predefined.

Everything else passes through: comments, formatting, other instructions, other data. Identifiers are matched
without regard to case, as RAPID does.

Refused, with the file and line: expressions as targets (``Offs(p10, 0, 0, 10)``, ``RelTool(...)``,
``CRobT()``), arrays of targets (``p{3}``), other motion instructions of the Move/Trigg/Search families
(``TriggL``, ``SearchL``, ``MoveLDO`` ...), a stationary tool (robhold TRUE), a work object held by the robot
or moved by a mechanical unit (ufprog FALSE), a target used with two tools or work objects, an unknown name,
a target assigned at run time (``p10 := ...`` or ``p10.trans.x := ...``), unbalanced brackets or quotes.
Limits: procedures, ``IF``/loops and calls are not followed: targets are taken in text order; external axes
(extax, 9E9 when absent) are copied, never corrected.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from robocal.cell.programs.common import (
    Program,
    ProgramError,
    Target,
    blank_to_line_end,
    format_number,
    line_of,
    read_text,
    reuse_target,
)
from robocal.kinematics.transforms import homogeneous, matrix_to_quat, quat_to_matrix

_DATA_TYPES = ("robtarget", "jointtarget", "tooldata", "wobjdata")
_DECL = re.compile(
    r"\s*(?:(?:LOCAL|TASK)\s+)?(CONST|PERS|VAR)\s+(\w+)\s+(\w+)\s*(\{[^}]*\})?\s*(?::=\s*)?",
    re.IGNORECASE | re.DOTALL,
)
_MOVES = {"movel": 1, "movej": 1, "movec": 2, "moveabsj": 1}
_MOVE_FAMILY = re.compile(r"^(Move|Trigg|Search|Arc|Spot|Paint|Cap)\w*$", re.IGNORECASE)
_NUM = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_LEAF = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w.])|[-+]?[\w.]+")


def _mask(text: str, file: Path) -> str:
    """``text`` with ``!`` comments replaced by spaces (same length); raises on an unterminated string."""
    out = list(text)
    i, n = 0, len(text)
    while i < n:
        ch = text[i]
        if ch == '"':
            j = i + 1
            while j < n and text[j] != '"' and text[j] != "\n":
                j += 1
            if j >= n or text[j] != '"':
                raise ProgramError("unterminated string", file, line_of(text, i))
            i = j + 1
            continue
        if ch == "!":
            i = blank_to_line_end(text, out, i)
            continue
        i += 1
    return "".join(out)


def _statements(code: str, text: str, file: Path) -> list[tuple[int, int]]:
    """Spans ``(start, end)`` of the statements of masked ``code``: ``;``-terminated at bracket depth 0."""
    out = []
    start, depth, i, n = 0, 0, 0, len(code)
    while i < n:
        ch = code[i]
        if ch == '"':
            i = code.index('"', i + 1) + 1
            continue
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
            if depth < 0:
                raise ProgramError(f"unbalanced {ch!r}", file, line_of(text, i))
        elif ch == ";":
            if depth != 0:
                raise ProgramError("unbalanced '[' or '(' before ';'", file, line_of(text, i))
            out.append((start, i + 1))
            start = i + 1
        i += 1
    if depth != 0:
        raise ProgramError("unbalanced '[' at the end of the file", file, line_of(text, start))
    return out


_BLOCK = re.compile(
    r"\s*(?:%%%.*?%%%|MODULE\s+\w+(?:\s*\([^)]*\))?|ENDMODULE|ENDPROC|ENDFUNC|ENDTRAP|ENDIF|ENDFOR|ENDWHILE|ENDTEST"
    r"|(?:LOCAL\s+)?(?:PROC|TRAP)\s+\w+\s*(?:\([^)]*\))?|(?:LOCAL\s+)?FUNC\s+\w+\s+\w+\s*\([^)]*\)"
    r"|(?:ELSE)?IF\b[^;]*?\bTHEN\b|ELSE\b|FOR\b[^;]*?\bDO\b|WHILE\b[^;]*?\bDO\b|TEST\b[^;\n]*|CASE\b[^;:]*:"
    r"|DEFAULT\s*:|ERROR\b(?:\s*\([^)]*\))?|BACKWARD\b|UNDO\b)",
    re.IGNORECASE | re.DOTALL,
)


def _skip_blocks(code: str, s: int, e: int) -> int:
    """The start of the statement proper in ``code[s:e]``, after block keywords that take no ``;``."""
    while True:
        m = _BLOCK.match(code, s, e)
        if not m or m.end() == s:
            break
        s = m.end()
    while s < e and code[s].isspace():
        s += 1
    return s


class Node:
    """A parsed RAPID value: a leaf (number, bool, string, name) or a list ``[...]``, with its span."""

    def __init__(self, start: int, end: int, items: list[Node] | None = None, leaf: str | None = None) -> None:
        self.start, self.end, self.items, self.leaf = start, end, items, leaf

    def numbers(self, file: Path, text: str, what: str, n: int | None = None) -> list[float]:
        if self.items is None or any(it.leaf is None or not _NUM.fullmatch(it.leaf) for it in self.items):
            raise ProgramError(f"{what} must be a list of numbers", file, line_of(text, self.start))
        if n is not None and len(self.items) != n:
            raise ProgramError(f"{what} must have {n} numbers, has {len(self.items)}", file, line_of(text, self.start))
        return [float(it.leaf or 0) for it in self.items]

    def item(self, k: int, file: Path, text: str, what: str) -> Node:
        if self.items is None or len(self.items) <= k:
            raise ProgramError(f"{what}: the value has too few parts", file, line_of(text, self.start))
        return self.items[k]


def parse_value(code: str, start: int, end: int, file: Path, text: str) -> Node:
    """Parse the aggregate ``code[start:end]`` (masked; comments blank)."""
    i = start

    def skip() -> None:
        nonlocal i
        while i < end and code[i].isspace():
            i += 1

    def value() -> Node:
        nonlocal i
        skip()
        if i >= end:
            raise ProgramError("value ends early", file, line_of(text, start))
        if code[i] == "[":
            s = i
            i += 1
            items: list[Node] = []
            skip()
            if i < end and code[i] == "]":
                i += 1
                return Node(s, i, items)
            while True:
                items.append(value())
                skip()
                if i < end and code[i] == ",":
                    i += 1
                    continue
                if i < end and code[i] == "]":
                    i += 1
                    return Node(s, i, items)
                raise ProgramError("expected ',' or ']' in a value", file, line_of(text, i))
        s = i
        if code[i] == '"':
            i = code.index('"', i + 1) + 1
            return Node(s, i, leaf=code[s:i])
        m = _LEAF.match(code, i)
        if not m:
            raise ProgramError(f"cannot read the value at {code[i : i + 20]!r}", file, line_of(text, i))
        i = m.end()
        return Node(s, i, leaf=m.group(0))

    node = value()
    skip()
    if i != end:
        raise ProgramError(f"unexpected text after the value: {code[i:end].strip()[:30]!r}", file, line_of(text, i))
    return node


def _pose(node: Node, file: Path, text: str, what: str) -> np.ndarray:
    t = node.item(0, file, text, what).numbers(file, text, f"{what} position", 3)
    q = np.array(node.item(1, file, text, what).numbers(file, text, f"{what} orientation", 4))
    nq = float(np.linalg.norm(q))
    if not 0.99 < nq < 1.01:
        raise ProgramError(f"{what}: the quaternion is not normalised (norm {nq:.5f})", file, line_of(text, node.start))
    return homogeneous(quat_to_matrix(q / nq), np.asarray(t, dtype=float))


class _Data:
    def __init__(self, typ: str, name: str, node: Node | None, line: int, array: bool) -> None:
        self.typ, self.name, self.node, self.line, self.array = typ, name, node, line, array


def read_rapid(path: str | Path) -> Program:
    """Read a RAPID module (``.mod``)."""
    file = Path(path)
    if not file.is_file():
        raise ProgramError("no such RAPID module", file)
    text = read_text(file)
    code = _mask(text, file)
    stmts = _statements(code, text, file)
    data: dict[str, _Data] = {}
    moves: list[tuple[int, int, str]] = []
    for s, e in stmts:
        st = _skip_blocks(code, s, e - 1)
        m = _DECL.match(code, st, e - 1)
        if m and m.group(2).lower() in _DATA_TYPES:
            typ, name = m.group(2).lower(), m.group(3)
            line = line_of(text, m.start(3))
            if ":=" not in code[st : m.end()] and m.end() < e - 1 and code[m.end() : e - 1].strip():
                raise ProgramError(f"cannot read the declaration of {name}", file, line)
            if m.group(4):
                data[name.lower()] = _Data(typ, name, None, line, True)
                continue
            vs = m.end()
            node = parse_value(code, vs, e - 1, file, text) if code[vs : e - 1].strip() else None
            data[name.lower()] = _Data(typ, name, node, line, False)
            continue
        mm = re.match(r"(\w+)", code[st : e - 1])
        if mm:
            moves.append((st, e - 1, mm.group(1)))
    targets: dict[str, Target] = {}
    order: list[Target] = []
    for st, en, word in moves:
        line = line_of(text, st)
        wl = word.lower()
        if wl in _MOVES:
            _move(code, text, file, st, en, word, data, targets, order, line)
            continue
        if _MOVE_FAMILY.match(word) and wl not in ("movejsync",):
            raise ProgramError(f"motion instruction {word} is not supported by the filter", file, line)
        am = re.match(r"(\w+)\s*(?:\.\s*\w+\s*)*:=", code[st:en])
        if am and am.group(1).lower() in data and data[am.group(1).lower()].typ in ("robtarget", "jointtarget"):
            raise ProgramError(
                f"target {am.group(1)} is assigned at run time; its value is not known before the run", file, line
            )
    if not order:
        raise ProgramError("no motion target found", file)
    return Program("rapid", {file: text}, order, file)


def _args(code: str, s: int, e: int) -> list[tuple[int, int]]:
    """Top-level comma-separated argument spans of ``code[s:e]``."""
    out, depth, start, i = [], 0, s, s
    while i < e:
        ch = code[i]
        if ch == '"':
            i = code.index('"', i + 1) + 1
            continue
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append((start, i))
            start = i + 1
        i += 1
    out.append((start, e))
    return out


def _split_opt(code: str, s: int, e: int) -> tuple[tuple[int, int], dict[str, str]]:
    """An argument ``value\\Opt:=x\\Sw`` -> (span of value, {opt lower: text})."""
    depth, i = 0, s
    while i < e:
        ch = code[i]
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        elif ch == "\\" and depth == 0:
            break
        i += 1
    opts = {}
    for m in re.finditer(r"\\\s*(\w+)\s*(?::=\s*([^\\]+))?", code[i:e]):
        opts[m.group(1).lower()] = (m.group(2) or "").strip()
    vs, ve = s, i
    while vs < ve and code[vs].isspace():
        vs += 1
    while ve > vs and code[ve - 1].isspace():
        ve -= 1
    return (vs, ve), opts


def _tool(data: dict[str, _Data], name: str, file: Path, text: str, line: int) -> np.ndarray:
    if name.lower() == "tool0":
        return np.eye(4)
    d = data.get(name.lower())
    if d is None or d.typ != "tooldata" or d.node is None:
        raise ProgramError(f"tool {name!r} is not a declared tooldata with a value", file, line)
    rob = d.node.item(0, file, text, name)
    if (rob.leaf or "").upper() != "TRUE":
        raise ProgramError(f"tool {name}: a stationary tool (robhold FALSE) is not supported", file, d.line)
    return _pose(d.node.item(1, file, text, name), file, text, f"tool {name}")


def _wobj(data: dict[str, _Data], name: str, file: Path, text: str, line: int) -> np.ndarray:
    if name.lower() == "wobj0":
        return np.eye(4)
    d = data.get(name.lower())
    if d is None or d.typ != "wobjdata" or d.node is None:
        raise ProgramError(f"work object {name!r} is not a declared wobjdata with a value", file, line)
    rob = (d.node.item(0, file, text, name).leaf or "").upper()
    ufprog = (d.node.item(1, file, text, name).leaf or "").upper()
    if rob != "FALSE" or ufprog != "TRUE":
        raise ProgramError(
            f"work object {name}: robhold must be FALSE and ufprog TRUE (fixed user frame)", file, d.line
        )
    uf = _pose(d.node.item(3, file, text, name), file, text, f"wobj {name} uframe")
    of = _pose(d.node.item(4, file, text, name), file, text, f"wobj {name} oframe")
    return uf @ of


def _move(
    code: str,
    text: str,
    file: Path,
    st: int,
    en: int,
    word: str,
    data: dict[str, _Data],
    targets: dict[str, Target],
    order: list[Target],
    line: int,
) -> None:
    n_pts = _MOVES[word.lower()]
    args = _args(code, st + len(word), en)
    pos: list[tuple[tuple[int, int], dict[str, str]]] = []
    for a, b in args:
        if not code[a:b].strip():
            continue
        span, opts = _split_opt(code, a, b)
        if span[0] == span[1]:
            continue  # a leading switch such as \Conc
        pos.append((span, opts))
    need = n_pts + 3  # points, speed, zone, tool
    if len(pos) < need:
        raise ProgramError(
            f"{word}: expected {need} arguments (targets, speed, zone, tool), got {len(pos)}", file, line
        )
    tool_name = code[pos[n_pts + 2][0][0] : pos[n_pts + 2][0][1]].strip()
    wobj_name = "wobj0"
    for _, opts in pos:
        if "wobj" in opts:
            wobj_name = opts["wobj"]
    tool = _tool(data, tool_name, file, text, line)
    base = _wobj(data, wobj_name, file, text, line)
    want = "jointtarget" if word.lower() == "moveabsj" else "robtarget"
    for (s, e), _ in pos[:n_pts]:
        arg = code[s:e]
        if arg.startswith("["):
            node = parse_value(code, s, e, file, text)
            t = _target("<inline>", want, node, file, text, line_of(text, s))
        elif re.fullmatch(r"\w+", arg):
            d = data.get(arg.lower())
            if d is None or d.typ != want:
                what = "not declared" if d is None else f"a {d.typ}"
                raise ProgramError(f"{word} target {arg!r} is {what}; expected a {want}", file, line)
            if d.array or d.node is None:
                raise ProgramError(
                    f"{word} target {arg!r}: arrays and targets without a value are not supported", file, line
                )
            key = arg.lower()
            if reuse_target(targets, key, tool, base, f"{tool_name}/{wobj_name}", file, line):
                continue
            t = _target(d.name, want, d.node, file, text, d.line)
            targets[key] = t
        else:
            raise ProgramError(
                f"{word} target {arg.strip()[:40]!r} is an expression; only names and values", file, line
            )
        t.tool, t.base, t.tool_name, t.base_name = tool, base, tool_name, wobj_name
        t.used_at.append((str(file), line))
        order.append(t)


def _target(name: str, typ: str, node: Node, file: Path, text: str, line: int) -> Target:
    t = Target(
        name=name, kind="pose" if typ == "robtarget" else "axis", file=file, line=line, span=(node.start, node.end)
    )
    t.data = {"node": node, "text": text}
    if typ == "robtarget":
        t.T_base_tcp = _pose(node, file, text, f"robtarget {name}")
        cf = node.item(2, file, text, name).numbers(file, text, f"robtarget {name} confdata", 4)
        t.config["cf"] = [int(v) for v in cf]
    else:
        t.q_deg = np.array(node.item(0, file, text, name).numbers(file, text, f"jointtarget {name} robax", 6))
    return t


def render(t: Target, new: dict[str, Any]) -> str:
    """The target's value with new pose + confdata (robtarget) or robax (jointtarget); extax text kept unless
    ``new`` has ``extax`` (the external axes' new values, mm, from ``eax_a``; the rest kept)."""
    node: Node = t.data["node"]
    text: str = t.data["text"]
    edits: list[tuple[int, int, str]] = []
    if "extax" in new:
        en = (node.items or [])[3 if t.kind == "pose" else 1]
        old = [text[it.start : it.end].strip() for it in en.items or []]
        vals = [format_number(float(v), 4) for v in new["extax"]] + old[len(new["extax"]) :]
        edits.append((en.start, en.end, "[" + ",".join(vals) + "]"))
    if t.kind == "pose":
        T = new["T_base_tcp"]
        q = matrix_to_quat(T[:3, :3])
        q = q / np.linalg.norm(q)
        pn, qn, cn = (node.items or [])[0:3]
        edits.append((pn.start, pn.end, "[" + ",".join(format_number(float(v), 4) for v in T[:3, 3]) + "]"))
        edits.append((qn.start, qn.end, "[" + ",".join(format_number(float(v), 9) for v in q) + "]"))
        if "cf" in new:
            edits.append((cn.start, cn.end, "[" + ",".join(str(int(v)) for v in new["cf"]) + "]"))
    else:
        rn = (node.items or [])[0]
        edits.append((rn.start, rn.end, "[" + ",".join(format_number(float(v), 5) for v in new["q_deg"]) + "]"))
    out, last = [], node.start
    for s, e, new_text in sorted(edits):
        out.append(text[last:s])
        out.append(new_text)
        last = e
    out.append(text[last : node.end])
    return "".join(out)
