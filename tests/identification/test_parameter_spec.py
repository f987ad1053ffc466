"""Parameters as a value (issue 32): a frozen :class:`ParameterSpec` (names, kinds, units, fixed patterns, held,
priority, bounds, scale) is what calibrate and plan resolve their fixed parameters and keep order through."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from robocal.errors import ConfigError
from robocal.identification.identifiability import PRIORITY, ParameterSpec, keep_order

SRC = Path(__file__).resolve().parents[2] / "src" / "robocal"
NAMES = ("theta1", "a2", "base_tx", "base_rz", "tool_T1_x", "tool_rot_T1_a")
KINDS = ("kinematic", "kinematic", "base", "base", "tool", "tool_rot")
UNITS = ("rad", "mm", "mm", "rad", "mm", "rad")


def test_a_spec_is_a_frozen_value_resolved_once() -> None:
    spec = ParameterSpec(NAMES, KINDS, UNITS, ("theta*",), "calibration.fixed")
    assert spec.fixed == {"theta1"} and spec.n == 6
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.held = frozenset({"a2"})  # type: ignore[misc]
    held = spec.holding(["base_rz"])
    assert held.fixed == {"theta1", "base_rz"} and held.held == {"base_rz"} and spec.held == frozenset()
    # frames, tools, then the joint-level parameters; fixed ones out: the function's order
    assert held.keep_order() == [2, 4, 5, 1] == keep_order(KINDS, NAMES, held.fixed)
    np.testing.assert_array_equal(held.indices(("base", "tool", "tool_rot")), [2, 4, 5])


def test_a_pattern_that_matches_nothing_names_the_setting() -> None:
    with pytest.raises(ConfigError, match=r"'plan\.fixed' setting names 'd\*', which matches no parameter"):
        ParameterSpec(NAMES, KINDS, UNITS, ("d*",), "plan.fixed")
    with pytest.raises(ConfigError, match="one kind"):
        ParameterSpec(NAMES, KINDS[:-1])
    with pytest.raises(ConfigError, match=r"holds \['d9'\]"):
        ParameterSpec(NAMES, KINDS).holding(["d9"])


def test_a_kind_of_the_callers_comes_after_the_priority_groups() -> None:
    """The plan's axis terms: candidates after the calibration's parameters, fixed by the same patterns."""
    names, kinds, units = (*NAMES, "axis_pos_1"), (*KINDS, "axis"), (*UNITS, "mm")
    spec = ParameterSpec(names, kinds, units, ("axis_*",), "plan.fixed", priority=(*PRIORITY, ("axis",)))
    assert spec.keep_order() == [2, 3, 4, 5, 0, 1]
    assert ParameterSpec(names, kinds, units, priority=(*PRIORITY, ("axis",))).keep_order()[-1] == 6
    assert 6 not in ParameterSpec(names, kinds, units).keep_order()  # a kind in no group is no candidate


def test_bounds_and_scale_around_a_point() -> None:
    x = np.arange(6.0)
    box = ParameterSpec(NAMES, KINDS, UNITS).around(x, 1.0, 0.002)
    assert box.lower is not None and box.upper is not None and box.scale is not None
    np.testing.assert_array_equal(box.scale, [0.002, 1.0, 1.0, 0.002, 1.0, 0.002])
    np.testing.assert_array_equal(box.lower, x - box.scale)  # the same arithmetic as the search box had
    np.testing.assert_array_equal(box.upper, x + box.scale)
    assert not box.lower.flags.writeable  # a value: its arrays are read-only


def _calls(path: Path, name: str) -> list[int]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Call) and ast.unparse(n.func).split(".")[-1] == name]


@pytest.mark.parametrize("module", ["calibration/start.py", "plan/planner.py", "identification/thin.py"])
def test_calibrate_and_plan_go_through_the_spec(module: str) -> None:
    path = SRC / module
    keep = [ast.unparse(n.func) for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(n, ast.Call) and ast.unparse(n.func).endswith("keep_order")]  # fmt: skip
    assert not _calls(path, "resolve_fixed"), "resolve the fixed patterns through ParameterSpec"
    assert keep and all(k != "keep_order" for k in keep), keep  # the spec's method, not the bare function


def test_a_calibration_start_carries_its_spec(tmp_path, kr16) -> None:
    from robocal.calibration.config import CalibrationConfig
    from robocal.calibration.start import calibration_start
    from robocal.data.contract import read_campaign
    from robocal.sim.twin import load_scenario, simulate

    sc = load_scenario("geometric")
    sc.update(n_poses=20, n_validation_poses=0)
    simulate(sc, tmp_path, seed=4)
    start = calibration_start(read_campaign(tmp_path, kr16), kr16, CalibrationConfig(fixed=("beta*",)), held=("d4",))
    spec = start.parameters
    assert spec.names == start.model.names and spec.setting == "calibration.fixed"
    assert "d4" in spec.fixed and spec.held == {"d4"}
    assert all(n.startswith("beta") or n == "d4" for n in spec.fixed)
    assert not set(start.model.names[i] for i in start.free) & spec.fixed
