"""No dead code in the library: vulture reads src/robocal with every user of it (stages, tests, benchmarks,
experiments) and finds no function, class, method or property nobody calls, nor a variable nobody reads, beyond
the names listed here with why they stay.

A name listed in a module's ``__all__`` and used nowhere is dead all the same: ``__all__`` is left out of what
vulture reads. vulture reads the code as text, so it cannot see a name used by string (a registry, a
``module:attribute`` reference) or a dataclass field read through ``asdict``; those are the allowed ones. A new
unused definition fails this test: delete it, or list it here with the reason it is kept.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

vulture = pytest.importorskip("vulture", reason="vulture is a dev tool (pyproject.toml, extra dev)")

REPO = Path(__file__).resolve().parents[1]
USERS = ["src", "stages", "tests", "benchmarks", "experiments"]

#: (file under src/robocal, name) -> why it is not dead
ALLOWED: dict[tuple[str, str], str] = {
    ("__init__.py", "__getattr__"): "the lazy public API: Python calls it",
    ("__init__.py", "__dir__"): "the lazy public API: Python calls it",
    ("cell/urdf.py", "robot_dict_from_ref"): "named by string in robot.URDF_DICT_READER",
    **{
        effect: "a twin effect, registered by name (register_effect)"
        for effect in (
            ("sim/effects.py", "TransmissionEffect"),
            ("sim/effects.py", "BacklashEffect"),
            ("sim/drift.py", "DriftEffect"),
            ("sim/drift.py", "ScaleEffect"),
            ("sim/stand.py", "CompliantStandEffect"),
            ("sim/stand.py", "LoggedChannelsEffect"),
            ("fleet/twin.py", "FleetState"),
            ("sim/axes.py", "LinearAxisEffect"),
            ("sim/session.py", "SecondSessionEffect"),
            ("sim/positioner.py", "PositionerEffect"),
        )
    },
    **{
        ("fleet/twin.py", f): "a fleet twin setting (conf/fleet/default.yaml), read through the settings parser"
        for f in (
            "serial_prefix",
            "interval_days",
            "tracker_jitter_mm",
            "gross_error_share",
            "jump_share",
            "drift_share",
            "jump_deg",
            "drift_mm_per_campaign",
        )
    },
    **{
        ("sim/twin.py", effect): "re-exported from the twin, the effect's home before issue 32's split"
        for effect in ("TransmissionEffect", "BacklashEffect")
    },
    ("discovery/scoring.py", "delta_bic"): "a field of a candidate's test, written to discovery.json (to_dict)",
    ("discovery/scoring.py", "excess_share"): "a field of a candidate's test, written to discovery.json (to_dict)",
    ("calibration/result.py", "residuals_deg"): "a field of the public CalibrationResult",
    ("metrics.py", "rms_deg"): "a field of ErrorStats, written by ErrorStats.orientation",
    ("metrics.py", "max_deg"): "a field of ErrorStats, written by ErrorStats.orientation",
    ("sim/closed_loop.py", "temperatures_C"): "a field of the public ClosedLoopResult",
    ("sim/closed_loop.py", "bundle_dir"): "a field of the public ClosedLoopResult",
}


def _without_all(code: str) -> str:
    """The module's code with its ``__all__`` assignment blanked (line numbers kept)."""
    lines = code.splitlines()
    for node in ast.parse(code).body:
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
            for i in range(node.lineno - 1, node.end_lineno or node.lineno):
                lines[i] = ""
    return "\n".join(lines)


def test_no_dead_code_in_the_library() -> None:
    v = vulture.Vulture()
    for folder in USERS:
        for path in sorted((REPO / folder).rglob("*.py")):
            v.scan(_without_all(path.read_text(encoding="utf-8")), filename=str(path))
    src = REPO / "src" / "robocal"
    found = {}
    for item in v.get_unused_code(min_confidence=60):
        path = Path(item.filename).resolve()
        if src in path.parents:
            found[(path.relative_to(src).as_posix(), item.name)] = f"{item.typ} line {item.first_lineno}"
    dead = {k: v for k, v in found.items() if k not in ALLOWED}
    assert not dead, f"unused in src/robocal (delete, or list in ALLOWED with why): {dead}"
    stale = sorted(set(ALLOWED) - set(found))
    assert not stale, f"ALLOWED names that are used now or gone (take them off the list): {stale}"
