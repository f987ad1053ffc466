"""mkdocs hook: the API reference's list of public names, read from ``robocal._API`` when the site is built.

``import robocal`` is lazy (it imports no submodule), so reading the table costs nothing; each entry becomes a
mkdocstrings directive ``::: module.attribute`` at the page's ``<!-- robocal-public-api -->`` marker.
"""

from __future__ import annotations

from typing import Any

MARKER = "<!-- robocal-public-api -->"


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if MARKER not in markdown:
        return markdown
    import robocal

    api: dict[str, str] = robocal._API  # public name -> "module:attribute"
    blocks = [f"::: {spec.replace(':', '.')}" for spec in api.values()]
    return markdown.replace(MARKER, "\n\n".join(blocks))
