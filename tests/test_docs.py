"""The README and the documentation pages (docs/*.md) say what runs: their code blocks and commands are checked.

* the README stays short (at most 200 lines, lines of at most 120 characters) and names no page that is missing;
* every python block compiles; the README's runs in tests/test_api.py, the pages' run under ``make e2e``;
* every ``robocal COMMAND --flag`` (code blocks and inline code) names a command and flags the CLI has;
* every ``make TARGET`` a Makefile target, every ``python stages|benchmarks/X.py`` and ``python -m robocal.X`` a
  file, every ``dvc exp run -S key=value`` a key of params.yaml, every repository path a file or folder that exists.

Nothing is built or run here but the python blocks' compilation; ``make docs`` (mkdocs --strict) checks the links
between the pages.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from robocal.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
PAGES = [README, *sorted((REPO / "docs").glob("*.md"))]

FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.M | re.S)
INLINE = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")
#: a path into the repository as the pages write it (placeholders such as <stage> or DIR are not paths)
REPO_PATH = re.compile(r"^(?:src|tests|benchmarks|stages|conf|docs|experiments)/[\w./-]*$")


def _blocks(lang: str) -> list[tuple[Path, str]]:
    found = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        found += [(page, m.group(2)) for m in FENCE.finditer(text) if m.group(1) == lang]
    return found


def _without_blocks(text: str) -> str:
    return FENCE.sub("", text)


def _shell_commands() -> list[tuple[Path, str]]:
    """Every command of the bash blocks (continuation lines joined, comments dropped) and every inline code span."""
    commands = []
    for page, block in _blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #", 1)[0].strip()
            if line and not line.startswith("#"):
                commands.append((page, line))
    for page in PAGES:
        commands += [(page, m.group(1)) for m in INLINE.finditer(_without_blocks(page.read_text(encoding="utf-8")))]
    return commands


def _cli_options() -> dict[str, set[str]]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {name: {o for a in p._actions for o in a.option_strings} for name, p in sub.choices.items()}


def test_the_readme_is_short_and_its_lines_are_too() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines: move the detail to a page under docs/"
    long = [i for i, line in enumerate(lines, 1) if len(line) > 120]
    assert not long, f"README.md lines over 120 characters: {long}"


def test_every_page_a_link_names_exists() -> None:
    missing = []
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#\s]+\.md)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if not (page.parent / target).is_file():
                missing.append(f"{page.relative_to(REPO)} -> {target}")
    assert not missing, missing
    nav = yaml.safe_load((REPO / "mkdocs.yml").read_text())["nav"]
    listed = {next(iter(item.values())) for item in nav}
    pages = {p.name for p in PAGES[1:]}
    assert pages == listed, f"docs pages not in mkdocs.yml's nav, or nav entries without a page: {pages ^ listed}"


@pytest.mark.parametrize("page,code", _blocks("python"), ids=lambda v: v.name if isinstance(v, Path) else "")
def test_python_blocks_compile(page: Path, code: str) -> None:
    compile(code, str(page), "exec")


@pytest.mark.e2e
def test_the_pages_python_blocks_run(tmp_path: Path) -> None:
    """The pages' examples run as written (minutes on the 2-core machine: make e2e; the README's: test_api.py)."""
    blocks = [(page, code) for page, code in _blocks("python") if page != README]
    assert blocks
    for page, code in blocks:
        out = subprocess.run(
            [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600, check=False
        )
        assert out.returncode == 0, f"{page.name}: {out.stderr[-3000:]}"


def test_robocal_commands_and_flags_exist() -> None:
    options = _cli_options()
    bad, seen = [], 0
    for page, command in _shell_commands():
        words = command.split()
        if len(words) < 2 or words[0] != "robocal" or not re.fullmatch(r"[a-z][a-z0-9-]*", words[1]):
            continue  # `robocal tracking: ...` is a message, `robocal.calibrate` a name
        seen += 1
        if words[1] not in options:
            bad.append(f"{page.name}: {command!r}: no command {words[1]!r}")
            continue
        for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", command):
            if flag not in options[words[1]]:
                bad.append(f"{page.name}: {command!r}: robocal {words[1]} has no {flag}")
    assert seen >= 20, f"only {seen} robocal commands found: has the pages' format changed?"
    assert not bad, "\n".join(bad)


def test_make_targets_scripts_and_dvc_keys_exist() -> None:
    targets = set(re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), re.M))
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    bad = []
    for page, command in _shell_commands():
        words = command.split()
        if len(words) >= 2 and words[0] == "make" and re.fullmatch(r"[a-z][a-z0-9-]*", words[1]):
            if words[1] not in targets:
                bad.append(f"{page.name}: {command!r}: no make target {words[1]!r}")
        for script in re.findall(r"\bpython (?:-m )?((?:stages|benchmarks)/\w+\.py)", command):
            if not (REPO / script).is_file():
                bad.append(f"{page.name}: {command!r}: no {script}")
        for module in re.findall(r"\bpython -m (robocal(?:\.\w+)*)", command):
            path = REPO / "src" / module.replace(".", "/")
            if not (path.with_suffix(".py").is_file() or (path / "__main__.py").is_file()):
                bad.append(f"{page.name}: {command!r}: no module {module}")
        if command.startswith("dvc exp run"):
            for key in re.findall(r"-S '?([\w.]+)=", command):
                node = params
                for part in key.split("."):
                    if not isinstance(node, dict) or part not in node:
                        bad.append(f"{page.name}: {command!r}: params.yaml has no {key!r}")
                        break
                    node = node[part]
    assert not bad, "\n".join(bad)


def test_repository_paths_exist() -> None:
    bad = []
    for page in PAGES:
        for span in INLINE.findall(_without_blocks(page.read_text(encoding="utf-8"))):
            for word in span.split():
                word = word.strip("(),;:")
                if REPO_PATH.match(word) and not (REPO / word.rstrip("/")).exists():
                    bad.append(f"{page.name}: {word}")
    assert not bad, "paths the pages name that do not exist:\n" + "\n".join(bad)


def test_the_site_builds_offline(tmp_path: Path) -> None:
    """``make docs``: mkdocs --strict (every page in the nav, every link and API reference resolves) builds the
    site, and no page loads anything from the network (fonts, scripts, styles)."""
    pytest.importorskip("mkdocs", reason="mkdocs-material is a dev tool (pyproject.toml, extra dev)")
    site = tmp_path / "site"
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir", str(site)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert out.returncode == 0, out.stderr[-3000:]
    pages = sorted(site.glob("*.html"))
    assert {p.stem for p in pages} >= {"index", "reference", *(p.stem for p in PAGES[1:])}
    remote = re.compile(r"<(?:script|link|img)\b[^>]*\b(?:src|href)=\"(?:https?:)?//", re.I)
    loads = {p.name: remote.findall(p.read_text(encoding="utf-8")) for p in pages}
    assert not any(loads.values()), {k: v for k, v in loads.items() if v}
    assert "robocal.data.contract.read_campaign" in (site / "reference.html").read_text(encoding="utf-8")
