"""The one settings parser (robocal.config) and every settings section built with it.

Each error is a ConfigError in one format: ``<section>.<key>: <what is expected>; got <value>``.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import pytest
from omegaconf import OmegaConf

from robocal.commands import parse_overrides
from robocal.config import SettingError, check_fields, parse, setting
from robocal.errors import ConfigError

# ------------------------------------------------------------------------------------------- a toy section


@dataclass(frozen=True)
class Inner:
    n: int = setting(1, ge=1)
    name: str = "a"


@dataclass(frozen=True)
class Toy:
    rate: float = setting(0.5, gt=0, lt=1)
    count: int = setting(3, ge=0)
    flag: bool = False
    mode: str = setting("fast", choices=("fast", "slow"))
    kind: Literal["x", "y"] = "x"
    names: tuple[str, ...] = ()
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    limit: float | None = None
    rows: str | tuple[int, ...] = setting("auto", choices=("auto", "off"))
    extra: Mapping[str, Any] = field(default_factory=dict)
    inner: Inner = field(default_factory=Inner)
    even: int = setting(2, check=lambda v: None if v % 2 == 0 else "must be even")
    secret: str | None = setting(None, settable=False)


@dataclass(frozen=True)
class Ordered:
    low: float = 0.0
    high: float = 1.0

    def validate(self) -> None:
        if self.low >= self.high:
            raise SettingError("low", "must be below high", self.low)


def _raises(key: str, cfg: Any, cls: type = Toy, section: str = "toy") -> ConfigError:
    """The error of parsing ``cfg``; asserts that it is a ConfigError naming ``key`` at the start."""
    with pytest.raises(ConfigError) as info:
        parse(cls, cfg, section)
    assert str(info.value).startswith(f"{key}: "), str(info.value)
    return info.value


def test_defaults_from_none_and_empty() -> None:
    assert parse(Toy, None, "toy") == Toy() == parse(Toy, {}, "toy")


def test_values_are_converted_by_the_type_hints() -> None:
    t = parse(Toy, {"rate": 0.25, "count": 7, "names": ["a", "b"], "point": [1, 2, 3], "rows": [2, 5]}, "toy")
    assert t.rate == 0.25 and t.count == 7
    assert t.names == ("a", "b") and t.rows == (2, 5)  # lists become tuples
    assert t.point == (1.0, 2.0, 3.0) and all(type(x) is float for x in t.point)  # ints become floats
    assert parse(Toy, {"rate": 1 - 1e-9}, "toy").rate == pytest.approx(1 - 1e-9, abs=0)  # exact: no conversion


def test_unknown_key_suggests_the_close_one_and_lists_the_known() -> None:
    err = _raises("toy.raet", {"raet": 0.1})
    text = str(err)
    assert "unknown setting" in text and "Did you mean 'rate'?" in text
    assert "Known: count, even, extra, flag, inner, kind, limit, mode, names, point, rate, rows" in text
    assert "secret" not in text  # not a setting (settable=False)
    _raises("toy.secret", {"secret": "s3cret"})
    assert "Did you mean" not in str(_raises("toy.zzz", {"zzz": 1}))  # nothing close: no guess


def test_wrong_type() -> None:
    assert "must be an integer >= 0; got 'three'" in str(_raises("toy.count", {"count": "three"}))
    _raises("toy.count", {"count": 2.5})  # no silent truncation of a float
    _raises("toy.mode", {"mode": 3})
    _raises("toy.names", {"names": "a"})  # a string is not a list of one string
    _raises("toy.names[1]", {"names": ["a", 2]})
    _raises("toy.extra", {"extra": [1, 2]})
    _raises("toy.point", {"point": [1.0, 2.0]})  # three numbers


def test_bounds_and_one_format() -> None:
    err = _raises("toy.rate", {"rate": 2.0})
    assert str(err) == "toy.rate: must be in (0, 1); got 2.0"
    assert isinstance(err, SettingError) and (err.key, err.value) == ("toy.rate", 2.0)
    _raises("toy.rate", {"rate": 0})
    _raises("toy.count", {"count": -1})
    _raises("toy.rate", {"rate": float("nan")})
    assert "finite" in str(_raises("toy.rate", {"rate": float("inf")}))


def test_choices_literal_and_unions() -> None:
    assert "must be one of ['fast', 'slow']; got 'medium'" in str(_raises("toy.mode", {"mode": "medium"}))
    _raises("toy.kind", {"kind": "z"})
    assert parse(Toy, {"kind": "y"}, "toy").kind == "y"
    # str | tuple[int, ...]: a string from the choices, or a list of integers
    assert parse(Toy, {"rows": "off"}, "toy").rows == "off"
    assert "must be one of ['auto', 'off'] or a list of integers; got 'sometimes'" in str(
        _raises("toy.rows", {"rows": "sometimes"})
    )
    _raises(r"toy.rows[1]", {"rows": [2, "x"]})  # the list member's own error, naming the item
    # float | None
    assert parse(Toy, {"limit": None}, "toy").limit is None
    assert parse(Toy, {"limit": 3}, "toy").limit == 3.0
    _raises("toy.limit", {"limit": "big"})


def test_bool_is_never_a_number_nor_a_number_a_bool() -> None:
    _raises("toy.count", {"count": True})
    _raises("toy.rate", {"rate": False})
    _raises("toy.flag", {"flag": 1})
    _raises("toy.flag", {"flag": "yes"})
    assert parse(Toy, {"flag": True}, "toy").flag is True


def test_nested_sections_name_the_full_key() -> None:
    assert parse(Toy, {"inner": {"n": 5}}, "toy").inner == Inner(n=5)
    assert parse(Toy, {"inner": None}, "toy").inner == Inner()  # null: the defaults
    _raises("toy.inner.n", {"inner": {"n": 0}})
    assert "Did you mean 'name'?" in str(_raises("toy.inner.nmae", {"inner": {"nmae": "b"}}))
    _raises("toy.inner", {"inner": 3})
    _raises("outer.toy.rate", {"rate": 5}, section="outer.toy")


def test_custom_check_and_validate_hook() -> None:
    assert "must be even; got 3" in str(_raises("toy.even", {"even": 3}))
    assert parse(Ordered, {"low": 1, "high": 2}, "range") == Ordered(1.0, 2.0)
    assert str(_raises("range.low", {"low": 3.0, "high": 2.0}, Ordered, "range")) == (
        "range.low: must be below high; got 3.0"
    )


def test_omegaconf_nodes_are_plain_mappings() -> None:
    node = OmegaConf.create({"rate": 0.2, "names": ["a"], "inner": {"n": 4}, "extra": {"k": [1, 2]}})
    t = parse(Toy, node, "toy")
    assert t == Toy(rate=0.2, names=("a",), inner=Inner(n=4), extra={"k": [1, 2]})
    assert type(t.extra) is dict and type(t.extra["k"]) is list  # no OmegaConf containers left inside
    _raises("toy.rate", OmegaConf.create({"rate": 7}))
    _raises("toy", OmegaConf.create([1, 2]))  # a section must be a mapping


def test_cli_overrides_as_a_user_writes_them() -> None:
    # YAML 1.1 (key=value overrides) leaves 1e-3 a string: read as a number where a number is expected
    ov = parse_overrides(["rate=1e-3", "count=4", "names=[a, b]", "inner.n=2", "limit=2.5E+1"])
    assert ov["rate"] == "1e-3"
    t = parse(Toy, ov, "toy")
    assert t.rate == pytest.approx(1e-3, rel=0, abs=0) and t.limit == 25.0
    assert t.count == 4 and t.names == ("a", "b") and t.inner.n == 2
    _raises("toy.rate", parse_overrides(["rate=0.5x"]))
    _raises("toy.rate", {"rate": "0.5"})  # a quoted number is a string: only YAML 1.1's blind spot is read
    assert parse(Toy, parse_overrides(["inner.name=1e-3"]), "toy").inner.name == "1e-3"  # a string stays one


def test_ignored_keys_and_required_fields() -> None:
    assert parse(Toy, {"rate": 0.1, "report": True}, "toy", ignore=("report",)).rate == 0.1

    @dataclass(frozen=True)
    class Needs:
        where: str

    assert str(_raises("need.where", {}, Needs, "need")) == "need.where: is required; got nothing"


def test_check_fields_checks_direct_construction() -> None:
    @dataclass(frozen=True)
    class Direct:
        share: float = setting(0.5, ge=0, lt=1)

        def __post_init__(self) -> None:
            check_fields(self, "direct")

    with pytest.raises(ConfigError, match=re.escape("direct.share: must be in [0, 1); got 1.0")):
        Direct(share=1.0)


# ------------------------------------------------------------------------------- every settings section
# each: a bad value raises ConfigError naming <section>.<key>; defaults parse from None


def _section_cases() -> list[tuple[Any, dict[str, Any], str]]:
    from robocal.calibration.config import CalibrationConfig
    from robocal.compliance.fit import ComplianceConfig
    from robocal.data.contract import SplitConfig
    from robocal.discovery.config import DiscoveryConfig
    from robocal.fleet.twin import TwinSettings
    from robocal.plan.config import PlanConfig
    from robocal.serve.protocol import ServiceConfig
    from robocal.serve.server import ServerConfig
    from robocal.thermal.compensate import CompensationLimits
    from robocal.thermal.fit import ThermalConfig
    from robocal.thermal.regression import RegressionConfig
    from robocal.thermal.screening.config import ScreeningConfig, SelectionConfig

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))  # the experiment's settings
    from optimizer_comparison import CompareSettings

    return [
        (CalibrationConfig, {"outlier_alpha": 2.0}, "calibration.outlier_alpha"),
        (CalibrationConfig, {"noise_mm": 0}, "calibration.noise_mm"),
        (CalibrationConfig, {"outliers": [1, 5]}, "calibration.outliers"),
        (CalibrationConfig, {"method": "newton"}, "calibration.method"),
        (ComplianceConfig, {"kind": "magic"}, "compliance.kind"),
        (ComplianceConfig, {"t_min": -1}, "compliance.t_min"),
        (DiscoveryConfig, {"cv_folds": 1}, "discovery.cv_folds"),
        (DiscoveryConfig, {"effects": ["gear", "wobble"]}, "discovery.effects[1]"),
        (DiscoveryConfig, {"outlier_alpha": 0}, "discovery.outlier_alpha"),
        (ServiceConfig, {"max_targets": 0}, "serve.max_targets"),
        (ServiceConfig, {"safety": {"on_joint_limits": "ignore"}}, "serve.safety.on_joint_limits"),
        (ServiceConfig, {"solver": {"tol_mm": -1.0}}, "serve.solver.tol_mm"),
        (ServiceConfig, {"token": "s3cret"}, "serve.token"),  # never from a config file
        (ServerConfig, {"read_timeout_s": 0}, "serve.read_timeout_s"),
        (ServerConfig, {"prot": 80}, "serve.prot"),
        (PlanConfig, {"criterion": "E"}, "plan.criterion"),
        (PlanConfig, {"tracker": {"min_range_mm": 5.0, "max_range_mm": 4.0}}, "plan.tracker.min_range_mm"),
        (PlanConfig, {"volume": {"kind": "iso9283"}}, "plan.volume.center_mm"),
        (PlanConfig, {"targets": {"T1": {"position_mm": [0, 0, 1], "normal": [0, 0, 0]}}}, "plan.targets.T1.normal"),
        (CompareSettings, {"populations": [500, 2]}, "compare.populations[1]"),
        (CompareSettings, {"algorithms": []}, "compare.algorithms"),
        (SplitConfig, {"validation_fraction": 1.0}, "split.validation_fraction"),
        (SelectionConfig, {"top_k": 0}, "screen.selection.top_k"),
        (ScreeningConfig, {"drift": {"d1": [0.1], "d4": [0.1, 0.2]}}, "screen.drift"),
        (ScreeningConfig, {"selection": {"rule": "best"}}, "screen.selection.rule"),
        (ThermalConfig, {"proposed": "some"}, "thermal.proposed"),
        (ThermalConfig, {"regression": {"max_order": 0}}, "thermal.regression.max_order"),
        (ThermalConfig, {"compensation": {"on_joint_limits": "x"}}, "thermal.compensation.on_joint_limits"),
        (RegressionConfig, {"cv_tolerance": -0.1}, "thermal.regression.cv_tolerance"),
        (CompensationLimits, {"on_joint_limits": "yes"}, "safety.on_joint_limits"),
        (TwinSettings, {"jump_share": 1.5}, "fleet.twin.jump_share"),
        (TwinSettings, {"errors": {"length_mm": -0.1}}, "fleet.twin.errors.length_mm"),
        (TwinSettings, {"start": "2026-13-01"}, "fleet.twin.start"),
    ]


@pytest.mark.parametrize("case", range(len(_section_cases())))
def test_every_section_names_the_key(case: int) -> None:
    cls, cfg, key = _section_cases()[case]
    assert cls.from_mapping(None) == cls()
    with pytest.raises(ConfigError) as info:
        cls.from_mapping(cfg)
    assert str(info.value).startswith(f"{key}: "), str(info.value)


def test_sections_keep_their_special_forms() -> None:
    from datetime import date

    from robocal.calibration.config import CalibrationConfig
    from robocal.fleet.twin import TwinSettings
    from robocal.plan.config import PlanConfig
    from robocal.serve.protocol import ServiceConfig
    from robocal.thermal.regression import RegressionConfig
    from robocal.thermal.screening.config import ScreeningConfig

    # outliers: auto | off | [file rows]; key=value overrides read "off" as YAML 1.1 false
    assert CalibrationConfig.from_mapping(parse_overrides(["outliers=off"])).outliers == "off"
    assert CalibrationConfig.from_mapping({"outliers": [2, 9], "fixed": ["beta*"]}).outliers == (2, 9)
    # plan: criterion in any case, targets {name: spec or [x, y, z]} with unit normals
    p = PlanConfig.from_mapping(
        {"criterion": "a", "targets": {"A": [1, 2, 3], "B": {"position_mm": [0, 0, 1], "normal": [0, 0, 2]}}}
    )
    assert p.criterion == "A"
    assert [(t.name, t.position_mm, t.normal) for t in p.targets] == [
        ("A", (1.0, 2.0, 3.0), (0.0, 0.0, 1.0)),
        ("B", (0.0, 0.0, 1.0), (0.0, 0.0, 1.0)),  # normalised
    ]
    assert PlanConfig.from_mapping({"measured_by_twin": True}) == PlanConfig()  # the pipeline's switch
    # service token: from the argument only
    assert ServiceConfig.from_mapping({"max_targets": 5}, token="t").token == "t"
    # screening: one tool point or {name: point}; a single drift value is one state
    s = ScreeningConfig.from_mapping({"tool_mm": {"T1": [1, 2, 3]}, "drift": {"d1": 0.1}, "drift_state": 0})
    assert s.tool_mm == ((1.0, 2.0, 3.0),) and s.drift == {"d1": (0.1,)} and s.drift_state == 0
    assert ScreeningConfig.from_mapping({"tool_mm": [1, 2, 3]}).tool_mm == ((1.0, 2.0, 3.0),)
    # regression candidates: 'auto' or {parameter: [sensors]}; the 'auto' choice is not asked of the sensor names
    assert RegressionConfig.from_mapping({"candidates": {"d1": ["T_l1_C"]}}).candidates == {"d1": ("T_l1_C",)}
    # fleet twin: YAML reads an unquoted date as a date; a partial 'errors' keeps the other default
    t = TwinSettings.from_mapping({"start": date(2026, 2, 1), "errors": {"length_mm": 0.5}})
    assert t.start == "2026-02-01" and (t.errors.length_mm, t.errors.angle_deg) == (0.5, 0.02)


def test_optimizer_overrides_share_the_format() -> None:
    """The optimizer's keys come from its YAML file (no dataclass): the unknown-key error is the same."""
    from robocal.commands.calibrate import optimizer_config

    with pytest.raises(
        ConfigError, match=r"^optimizer\.populaton: unknown setting; got 5\. Did you mean 'population'\?"
    ):
        optimizer_config({"name": "woa", "populaton": 5})


def test_a_misspelt_constraint_is_a_bug_not_a_silent_no_op() -> None:
    @dataclass(frozen=True)
    class Typo:
        x: float = field(default=1.0, metadata={"gte": 0})

    with pytest.raises(TypeError, match="gte"):
        parse(Typo, {}, "typo")


def test_a_bare_on_or_off_reads_as_the_choice_not_a_boolean():
    """Newcomer pass 12: `robocal discover ... counterbalance=on` (as the docs write it) was refused, the override
    read as YAML 1.1 (`on` -> True): "must be one of ['auto', 'on', 'off']; got True"."""
    from robocal.discovery.config import DiscoveryConfig

    assert DiscoveryConfig.from_mapping({"counterbalance": True}).counterbalance == "on"
    assert DiscoveryConfig.from_mapping({"counterbalance": False}).counterbalance == "off"
    assert DiscoveryConfig.from_mapping({"counterbalance": "auto"}).counterbalance == "auto"
    with pytest.raises(SettingError):  # a setting whose choices are not on / off still refuses a boolean
        DiscoveryConfig.from_mapping({"geometry_prior": True})
