"""griffe extension for the API reference: the docstrings' one-line section entries, ``name : what it is``.

robocal's docstrings write a short parameter (or attribute, return) entry on one line, ``split : used when ...``,
where numpy style reads the text after the colon as the *type*. An entry with no indented description below it
is rewritten here, for the site only, to ``name`` with the text as its description; a full numpy entry (a type,
then an indented description) is left as it is.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

SECTIONS = {"Parameters", "Other Parameters", "Attributes", "Returns", "Yields", "Raises", "Warns"}
ENTRY = re.compile(r"^(\s*)([\w*, ]+?) : (.+)$")


def rewrite(text: str) -> str:
    """``text`` with every one-line entry of a numpy section turned into ``name`` + an indented description."""
    lines = text.splitlines()
    out: list[str] = []
    section = None
    for i, line in enumerate(lines):
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if line.strip() and re.fullmatch(r"\s*-{3,}\s*", nxt):  # a section header: the title over dashes
            section = line.strip()
        m = ENTRY.match(line)
        if section in SECTIONS and m:
            indent = m.group(1)
            described = nxt.strip() and len(nxt) - len(nxt.lstrip()) > len(indent)
            if not described:
                out += [f"{indent}{m.group(2)}", f"{indent}    {m.group(3)}"]
                continue
        out.append(line)
    return "\n".join(out)


class ShortEntries(griffe.Extension):
    def on_instance(self, *, node: Any, obj: griffe.Object, agent: Any, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = rewrite(obj.docstring.value)
