"""Calibration bundles: the models the compensation service loads, in one directory.

Layout::

    bundle/
      manifest.json       {"format": "robocal-bundle", "version": 1, "robot": "kr16_2" | "robot.yaml",
                           "calibration": "calibration.json", "thermal": "thermal.json" | null,
                           "compliance": "compliance.json" | null, "created": ISO time,
                           "sha256": {file name: hex digest, ...}}
      calibration.json    geometric calibration (robocal.calibration.result.CalibrationResult.to_dict);
                          a calibration written by ``robocal discover`` also carries its joint-level effects
                          (gear, backlash, compliance), applied like the compliance model's deflection
      thermal.json        optional: robocal.thermal.model.ThermalModel
      compliance.json     optional: robocal.compliance.model.ComplianceModel
      robot.yaml          optional: the robot description when ``robot`` names a file

Every file listed in ``sha256`` is checked on load; a bundle is loaded completely (and checked) before the
server swaps it in, so a half-written or inconsistent bundle never replaces a good one.

Thermal model interface used: ``.sensors`` (sensor names, in the order ``deta`` expects), the fitted
temperature range (``temperature_range`` (s, 2) or ``fitted_range`` / ``t_min, t_max``; see
:func:`thermal_range`) and ``.deta(T (m, s)) -> (m, P)`` kinematic parameter drift in the chain's parameter
order. Compliance: ``.joint_offsets(q (m, n), payload_kg (m,), current_A (m, n) | None, tau_Nm (m, n) | None)
-> dq (m, n)`` joint deflection added to the commanded joints.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from robocal.calibration.load import load_calibration
from robocal.calibration.record import check_robot
from robocal.calibration.result import CalibrationResult
from robocal.compensation.effects import signal_ranges, signal_reasons
from robocal.errors import ConfigError
from robocal.identification.acceptance import too_few_configurations
from robocal.io import write_json
from robocal.kinematics.chain import Chain
from robocal.robot import SHIPPED_ROBOT_DIR, RobotDescription, find_robot, is_robot_path, load_robot

FORMAT = "robocal-bundle"
VERSION = 1
MANIFEST = "manifest.json"
#: default loaders of the optional models: kind -> "module:Class" with a ``from_json(path)`` classmethod
DEFAULT_LOADERS = {
    "thermal": "robocal.thermal.model:ThermalModel",
    "compliance": "robocal.compliance.model:ComplianceModel",
}

Loader = Callable[[Path], Any]


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _default_loader(kind: str) -> Loader:
    spec = DEFAULT_LOADERS[kind]
    mod, cls = spec.split(":")
    try:
        klass = getattr(importlib.import_module(mod), cls)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"the bundle has a {kind} model but {spec} is not available: {exc}") from exc
    return klass.from_json


def thermal_range(model: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """The fitted temperature range ``(lo (s,), hi (s,))`` in degC of a thermal model, or None if it has none."""
    for name in ("fitted_range_C", "temperature_range", "fitted_range", "fit_range", "range_C"):
        r = getattr(model, name, None)
        if r is not None:
            if callable(r):
                r = r()
            if isinstance(r, Mapping):  # {sensor: [lo, hi]}
                r = [r[s] for s in model.sensors]
            arr = np.asarray(r, dtype=float)
            if arr.ndim == 2 and arr.shape[1] == 2:
                return arr[:, 0], arr[:, 1]
            if arr.ndim == 2 and arr.shape[0] == 2:
                return arr[0], arr[1]
    for lo_name, hi_name in (("t_min", "t_max"), ("T_min", "T_max"), ("temperature_min", "temperature_max")):
        lo, hi = getattr(model, lo_name, None), getattr(model, hi_name, None)
        if lo is not None and hi is not None:
            s = len(model.sensors)
            return np.broadcast_to(np.asarray(lo, float), (s,)).copy(), np.broadcast_to(np.asarray(hi, float), (s,))
    return None


@dataclass(frozen=True)
class Bundle:
    """A loaded, checked bundle.

    robot, calibration : the geometric model; chain : ``calibration.model.chain``; eta0 : (P,) identified
    kinematic errors; tracker_T_base : (4, 4); tools : {target name: (4, 4) flange_T_tool};
    thermal / compliance : the optional models (None when absent); sensors : thermal sensor names;
    t_lo / t_hi : (s,) fitted temperature range or None; manifest : the manifest; bundle_id : short hash.
    """

    path: Path
    robot: RobotDescription
    calibration: CalibrationResult
    chain: Chain
    eta0: np.ndarray
    tracker_T_base: np.ndarray
    tools: dict[str, np.ndarray]
    thermal: Any = None
    compliance: Any = None
    sensors: tuple[str, ...] = ()
    t_lo: np.ndarray | None = None
    t_hi: np.ndarray | None = None
    manifest: dict[str, Any] = field(default_factory=dict)
    bundle_id: str = ""
    effects: tuple[dict[str, Any], ...] = ()  # discovered joint-level effects (robocal.compensation.discovered)
    #: a robot on external axes: their own errors along the travel (the calibration's ``axes``,
    #: :class:`robocal.calibration.axes.AxisFit`), or None
    axis_fit: Any = None

    @property
    def default_tool(self) -> str:
        return next(iter(self.tools))

    def joint_effects(self) -> list[Any]:
        """The bundle's joint-space effects, summed in this order (:mod:`robocal.compensation.effects`): the
        compliance model, the discovered joint-level effects. A new joint-space effect is listed here once and
        reaches the service and the program filter."""
        from robocal.compensation.effects import joint_effects

        return joint_effects(self.compliance, self._discovered)

    @cached_property
    def _discovered(self) -> Any:
        """The discovered effects, built once per loaded bundle (their tables are built at the first use)."""
        if not self.effects:
            return None
        from robocal.compensation.discovered import DiscoveredEffects

        return DiscoveredEffects(tuple(self.effects), self.robot)

    def eta_at(self, temperatures: np.ndarray | None) -> np.ndarray:
        """The robot's kinematic errors at these temperatures: the calibration's, plus the thermal drift when the
        bundle has a thermal model (``temperatures`` (s,) degC in the order of :attr:`sensors`)."""
        if self.thermal is None or temperatures is None:
            return self.eta0
        return self.eta0 + np.asarray(self.thermal.deta(np.asarray(temperatures, dtype=float)[None, :]), dtype=float)[0]

    def temperature_reasons(self, temperatures: np.ndarray, margin_C: float) -> list[str]:
        """One reason per sensor outside the thermal model's fitted range (widened by ``margin_C``)."""
        if self.t_lo is None or self.t_hi is None:
            return []
        t = np.asarray(temperatures, dtype=float)
        hot = np.flatnonzero((t < self.t_lo - margin_C) | (t > self.t_hi + margin_C))
        return [
            f"temperature {self.sensors[i]}={t[i]:.2f} degC outside the fitted range "
            f"[{self.t_lo[i]:.2f}, {self.t_hi[i]:.2f}]"
            for i in hot
        ]

    def signal_ranges(self) -> dict[str, list[float] | None]:
        """The logged signals the bundle's effects follow, with the values they were fitted on
        (:func:`robocal.compensation.effects.signal_ranges`)."""
        return signal_ranges(self.effects)

    def signal_reasons(self, logged: Mapping[str, np.ndarray] | None) -> dict[int, list[str]]:
        """Per target, the logged signals past the values their effects were fitted on (served flagged, never
        refused: :func:`robocal.compensation.effects.signal_reasons`)."""
        return signal_reasons(self.effects, logged)

    @property
    def arm(self) -> list[int]:
        """The arm's joints (the revolute ones, chain order)."""
        return [j for j in range(self.robot.n_joints) if not self.robot.prismatic[j]]

    @property
    def external(self) -> list[int]:
        """The external axes (the prismatic joints: a track, a column; ``E1``, ``E2`` .. in chain order)."""
        return [j for j in range(self.robot.n_joints) if self.robot.prismatic[j]]

    def info(self) -> dict[str, Any]:
        """What a client needs to know: robot, joints and limits, tools, sensors and their fitted range; a robot
        on external axes also its axes (``external_axes``, their limits in mm, the axis error terms served)."""
        lim = self.robot.q_limits
        ext: dict[str, Any] = {}
        if self.external:
            ext = {
                "external_axes": [self.robot.joint_names[j] for j in self.external],
                "external_limits_mm": lim[self.external].round(9).tolist(),
                "axis_errors": [] if self.axis_fit is None else [t.name for t in self.axis_fit.terms],
            }
        return {
            "bundle": self.bundle_id,
            "path": str(self.path),
            "created": self.manifest.get("created"),
            "robot": self.robot.name,
            "joints": [self.robot.joint_names[j] for j in self.arm],
            "q_limits_deg": np.rad2deg(lim[self.arm]).round(9).tolist(),
            **ext,
            "tools": list(self.tools),
            "thermal": self.thermal is not None,
            "compliance": self.compliance is not None,
            "effects": [e["key"] for e in self.effects],
            **({"signals": self.signal_ranges()} if self.signal_ranges() else {}),
            "sensors": list(self.sensors),
            "temperature_range_C": None
            if self.t_lo is None or self.t_hi is None
            else {s: [float(a), float(b)] for s, a, b in zip(self.sensors, self.t_lo, self.t_hi, strict=True)},
        }


def load_bundle(path: str | Path, loaders: Mapping[str, Loader] | None = None) -> Bundle:
    """Load and check the bundle in directory ``path``.

    loaders : optional ``{"thermal": fn, "compliance": fn}`` with ``fn(json_path) -> model`` (default
    :data:`DEFAULT_LOADERS`); used by tests with stand-in models.
    """
    d = Path(path)
    manifest = _read_manifest(d)
    robot_ref = manifest.get("robot")
    if not robot_ref:
        raise ConfigError(f"bundle {d}: {MANIFEST} must name the 'robot'")
    robot = load_robot(d / robot_ref if str(robot_ref).endswith((".yaml", ".yml")) else str(robot_ref))
    cal, axes = _read_calibration(d, manifest, robot)
    models = _read_models(d, manifest, loaders)
    axis_fit = _external_axes_checked(d, robot, cal, models, axes)
    th = models.get("thermal")
    sensors, t_lo, t_hi = _thermal_range_checked(d, th, robot, cal.model.chain.n_params)
    digest = hashlib.sha256(json.dumps(manifest, sort_keys=True).encode()).hexdigest()[:12]
    return Bundle(
        path=d.resolve(),
        robot=robot,
        calibration=cal,
        chain=cal.model.chain,
        eta0=cal.kinematic_errors,
        tracker_T_base=cal.tracker_T_base,
        tools=_tool_frames(cal),
        thermal=th,
        compliance=models.get("compliance"),
        sensors=sensors,
        t_lo=t_lo,
        t_hi=t_hi,
        manifest=manifest,
        bundle_id=digest,
        effects=cal.effects,
        axis_fit=axis_fit,
    )


def _read_manifest(d: Path) -> dict[str, Any]:
    """The bundle's manifest, checked: its format and version, and every listed file against its sha256."""
    mpath = d / MANIFEST
    if not mpath.is_file():
        raise ConfigError(f"bundle {d}: no {MANIFEST}")
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"bundle {d}: {MANIFEST} is not valid JSON: {exc}") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise ConfigError(f"bundle {d}: {MANIFEST} must be a mapping with format {FORMAT!r}")
    if int(manifest.get("version", 0)) != VERSION:
        raise ConfigError(f"bundle {d}: unsupported version {manifest.get('version')!r}; this robocal reads {VERSION}")
    for name, digest in dict(manifest.get("sha256") or {}).items():
        f = d / str(name)
        if not f.is_file():
            raise ConfigError(f"bundle {d}: {name} is listed in {MANIFEST} but missing")
        if _sha256(f) != digest:
            raise ConfigError(f"bundle {d}: {name} does not match its sha256 in {MANIFEST} (changed or half-written)")
    return manifest


def _read_calibration(
    d: Path, manifest: dict[str, Any], robot: RobotDescription
) -> tuple[CalibrationResult, dict[str, Any] | None]:
    """The bundle's calibration, read for ``robot`` (an error names the bundle and the file), and its external
    axes' errors (``axes``, :func:`robocal.calibration.axes.calibration_axes`) or None."""
    cal_file = d / str(manifest.get("calibration") or "calibration.json")
    try:
        data = json.loads(cal_file.read_text(encoding="utf-8"))
        return load_calibration(data, robot), data.get("axes")
    except ConfigError as exc:  # e.g. a calibration of another robot: the error names both
        raise ConfigError(f"bundle {d}: {cal_file.name}: {exc}") from None
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"bundle {d}: cannot load {cal_file.name}: {type(exc).__name__}: {exc}") from exc


def _tool_frames(cal: CalibrationResult) -> dict[str, np.ndarray]:
    """``{target name: (4, 4) flange_T_tool}`` of the calibration."""
    tools: dict[str, np.ndarray] = {}
    tool_R = cal.model.tool_rotations(cal.x)
    for k, (name, t) in enumerate(cal.tools.items()):
        T = np.eye(4)
        T[:3, :3] = tool_R[k]
        T[:3, 3] = t
        tools[name] = T
    return tools


def _read_models(d: Path, manifest: dict[str, Any], loaders: Mapping[str, Loader] | None) -> dict[str, Any]:
    """The thermal and compliance models the manifest lists (a model that fails to load names its file)."""
    models: dict[str, Any] = {}
    for kind in ("thermal", "compliance"):
        ref = manifest.get(kind)
        if not ref:
            continue
        f = d / str(ref)
        load = (loaders or {}).get(kind) or _default_loader(kind)
        try:
            models[kind] = load(f)
        except ConfigError:
            raise
        except Exception as exc:  # a model file that fails to load must name itself
            raise ConfigError(
                f"bundle {d}: cannot load the {kind} model {f.name}: {type(exc).__name__}: {exc}"
            ) from exc
    return models


def _thermal_range_checked(
    d: Path, th: Any, robot: RobotDescription, n_params: int
) -> tuple[tuple[str, ...], np.ndarray | None, np.ndarray | None]:
    """``(sensors, t_lo, t_hi)`` of the thermal model (empty and None without one), after checking that its
    drift has one value per chain parameter of ``robot``."""
    if th is None:
        return (), None, None
    sensors = tuple(str(s) for s in th.sensors)
    rng = thermal_range(th)
    t_lo, t_hi = rng if rng is not None else (None, None)
    probe = np.asarray(th.deta(np.full((1, len(sensors)), float(robot.T0_C or 20.0))))
    if probe.shape != (1, n_params):
        raise ConfigError(
            f"bundle {d}: thermal model deta returns shape {probe.shape}; expected (1, {n_params}) "
            f"(the parameters of {robot.name})"
        )
    return sensors, t_lo, t_hi


def _external_axes_checked(
    d: Path, robot: RobotDescription, cal: CalibrationResult, models: dict[str, Any], axes: Any
) -> Any:
    """A robot on external axes (issue 34) is corrected by :func:`robocal.compensation.axes.compensate_axes`: its
    geometry and its axes' own errors along the travel (the calibration's ``axes``, returned as an
    :class:`~robocal.calibration.axes.AxisFit`, None without), and the calibration's discovered effects (the joints'
    deflection, a base or tool a logged signal moves) with each target's signals. A thermal or compliance model is
    not applied on that path: such a bundle is refused by name rather than served without it."""
    if not robot.has_prismatic:
        if axes:
            raise ConfigError(f"bundle {d}: the calibration has 'axes' but robot {robot.name!r} has no external axis")
        return None
    names = [robot.joint_names[j] for j in range(robot.n_joints) if robot.prismatic[j]]
    extra = [k for k in ("thermal", "compliance") if models.get(k) is not None]
    if extra:
        raise ConfigError(
            f"bundle {d}: robot {robot.name!r} rides external axes {names}; its correction "
            f"(robocal.compensation.axes) takes the geometry and the axes' own errors, not the {', '.join(extra)}: "
            "bundle the calibration alone"
        )
    if not axes:
        return None
    if not isinstance(axes, dict):
        raise ConfigError(f"bundle {d}: the calibration's 'axes' must be a mapping (robocal calibrate writes it)")
    from robocal.calibration.axes import axis_fit_of

    return axis_fit_of(robot, axes, cal.x, where=f"bundle {d}: calibration 'axes'")


def write_bundle(
    out_dir: str | Path,
    robot: str | Path,
    calibration: str | Path,
    thermal: str | Path | None = None,
    compliance: str | Path | None = None,
    *,
    force: bool = False,
) -> Path:
    """Copy the model files into ``out_dir`` and write the manifest last (atomically) with their sha256.

    A calibration of too few joint configurations to determine the model (its fit record's ``configurations``,
    :mod:`robocal.identification.thin`) is refused unless ``force``.

    robot : a robot name or a YAML file (:func:`robocal.robot.find_robot`); a file, or a name found in the
        current project's ``conf/robot/`` rather than among the packaged robots, is copied as ``robot.yaml`` so
        that the bundle loads anywhere.
    """
    urdf = str(robot).endswith(".urdf") or ".urdf#" in str(robot)  # referenced as given (robocal.cell.urdf)
    rp = None if urdf else find_robot(robot)
    cal_path = Path(calibration)
    try:  # a calibration of another robot is refused before anything is written
        cal_data = json.loads(cal_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read the calibration {cal_path}: {exc}") from None
    rob = load_robot(robot if rp is None else rp)
    if isinstance(cal_data, dict):
        check_robot(cal_data, rob, f"the calibration {cal_path}")
        design = (cal_data.get("fit") or {}).get("configurations") if isinstance(cal_data.get("fit"), dict) else None
        if isinstance(design, dict) and not design.get("enough", True) and not force:
            raise ConfigError(
                f"the calibration {cal_path} is not fit to serve: {too_few_configurations(design)}. "
                "To write the bundle anyway: --force (write_bundle(..., force=True))"
            )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, str] = {}
    manifest: dict[str, Any] = {"format": FORMAT, "version": VERSION}
    if rp is not None and (is_robot_path(robot) or rp.resolve().parent != SHIPPED_ROBOT_DIR.resolve()):
        shutil.copyfile(rp, out / "robot.yaml")
        manifest["robot"] = "robot.yaml"
        files["robot.yaml"] = "robot.yaml"
    else:
        manifest["robot"] = str(robot)
    for kind, src in (("calibration", calibration), ("thermal", thermal), ("compliance", compliance)):
        if src is None:
            manifest[kind] = None
            continue
        sp = Path(src)
        if not sp.is_file():
            raise ConfigError(f"the {kind} file {sp} does not exist")
        name = f"{kind}.json"
        tmp = out / f".{name}.tmp"
        shutil.copyfile(sp, tmp)
        tmp.replace(out / name)
        manifest[kind] = name
        files[name] = name
    manifest["created"] = datetime.now(UTC).isoformat(timespec="seconds")
    manifest["sha256"] = {name: _sha256(out / name) for name in files}
    write_json(out / MANIFEST, manifest)
    return out
