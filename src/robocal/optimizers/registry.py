"""Build an optimizer from a config mapping (a Hydra ``optimizer`` group entry) without importing by name.

``make_optimizer(cfg)`` looks ``cfg["name"]`` (or ``cfg["_target_"]``) up in a registry of known
factories, so a config can only select optimizers the code registered: Hydra's ``optimizer=goa`` works and
nothing arbitrary is instantiated. The other keys are the optimizer's keyword arguments, except the
pipeline keys (:data:`PIPELINE_KEYS`), which the calling workflow reads with :func:`pipeline_options`.
Registered: ``gn``, ``lm``, ``ipopt``, ``igoa``, ``goa``, ``woa``; add more with :func:`register`.
"""

from __future__ import annotations

import functools
import inspect
import re
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from robocal.config import SettingError, unknown_choice, unknown_setting
from robocal.errors import ConfigError
from robocal.optimizers.goa import GOA, ImprovedGOA
from robocal.optimizers.gradient import GaussNewton, LevenbergMarquardt
from robocal.optimizers.ipopt import Ipopt
from robocal.optimizers.protocol import Optimizer, check_bool, check_choice, check_real
from robocal.optimizers.woa import WOA

__all__ = [
    "PIPELINE_KEYS",
    "aliases",
    "make_optimizer",
    "pipeline_options",
    "register",
    "registered",
    "unregister",
]

#: Keys of an optimizer config that are not constructor arguments.
#: ``polish``: run a Gauss-Newton polish from the population method's best (the workflow does it);
#: ``objective``: "nonlinear" (residuals of the full model) or "linearized" (dP - J dEta, eq. 9);
#: ``bound_mm`` / ``bound_deg``: half-width of the search box around the initial estimate (lengths / angles);
#: ``stop_error``: stop when the best fitness (mm) is below it; "auto" = 1.1 x the noise floor; null = never.
PIPELINE_KEYS = ("name", "_target_", "polish", "objective", "bound_mm", "bound_deg", "stop_error")
OBJECTIVE_KINDS = ("nonlinear", "linearized")

Factory = Callable[..., Optimizer]


@dataclass(frozen=True)
class _Entry:
    factory: Factory
    target: str | None


_REGISTRY: dict[str, _Entry] = {}


def _target_of(factory: Factory) -> str | None:
    module = getattr(factory, "__module__", None)
    qualname = getattr(factory, "__qualname__", None)
    if module and qualname and "<" not in qualname:
        return f"{module}.{qualname}"
    return None


def register(name: str, factory: Factory, *, target: str | None = None, overwrite: bool = False) -> None:
    """Make ``factory(**kwargs) -> Optimizer`` available to :func:`make_optimizer` as ``name``.

    ``target`` is the ``_target_`` string a config may use for it (default: the factory's import path).
    """
    if not isinstance(name, str) or not name:
        raise ConfigError(f"The 'name' parameter of register must be a non-empty str. Got {name!r} instead.")
    if not callable(factory):
        raise ConfigError(f"The 'factory' parameter of register must be callable. Got {factory!r} instead.")
    if name in _REGISTRY and not overwrite:
        raise ConfigError(
            f"The 'name' parameter of register must be new (or pass overwrite=True). Got {name!r}, already registered."
        )
    _REGISTRY[name] = _Entry(factory, target if target is not None else _target_of(factory))


def unregister(name: str) -> None:
    """Remove ``name`` from the registry (tests, plugins); unknown names raise :class:`ConfigError`."""
    if name not in _REGISTRY:
        raise ConfigError(f"The 'name' parameter of unregister must be registered. Got {name!r} instead.")
    del _REGISTRY[name]


def registered(family: str | None = None) -> tuple[str, ...]:
    """Names of the registered optimizers, sorted; only those of one ``family`` (the class attribute:
    ``"gradient"``, ``"population"``, ``"nlp"``) when given. The one list of optimizer names."""
    names = sorted(_REGISTRY)
    if family is None:
        return tuple(names)
    return tuple(n for n in names if getattr(_REGISTRY[n].factory, "family", None) == family)


def aliases() -> dict[str, str]:
    """Other spellings of the registered names, for "did you mean": each factory's class name, as written and
    split at its capitals (``LevenbergMarquardt``: ``levenbergmarquardt``, ``levenberg-marquardt``) -> name."""
    out: dict[str, str] = {}
    for name, entry in _REGISTRY.items():
        cls = getattr(entry.factory, "__name__", "")
        if cls and cls.lower() != name:
            out[cls.lower()] = name
            words = re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+", cls)
            out["-".join(words).lower()] = name
    return out


def _resolve(cfg: Mapping[str, Any]) -> str:
    name = cfg.get("name")
    target = cfg.get("_target_")
    if name is None and target is None:
        raise ConfigError(
            f"The optimizer config must have a 'name' or a '_target_' key. Got keys {sorted(map(str, cfg))} instead."
        )
    if name is not None and name not in _REGISTRY:
        raise unknown_choice("optimizer.name", name, registered(), aliases())
    by_target = [k for k, e in _REGISTRY.items() if target is not None and e.target == target]
    if target is not None and not by_target:
        known = sorted(e.target for e in _REGISTRY.values() if e.target)
        raise ConfigError(
            f"The '_target_' key of the optimizer config must be one of {known} (arbitrary classes are not "
            f"instantiated). Got {target!r} instead."
        )
    if name is None:
        return by_target[0]
    if target is not None and name not in by_target:
        raise ConfigError(
            f"The '_target_' key of the optimizer config must match its 'name' {name!r} "
            f"({_REGISTRY[name].target!r}). Got {target!r} instead."
        )
    return str(name)


def make_optimizer(cfg: Mapping[str, Any]) -> Optimizer:
    """Build the optimizer a config mapping names (by ``name`` or ``_target_``).

    Parameters
    ----------
    cfg : Mapping
        E.g. ``conf/optimizer/igoa.yaml`` as a dict or an OmegaConf ``DictConfig``: ``name`` and/or
        ``_target_``, the constructor's keyword arguments, and the :data:`PIPELINE_KEYS`, which are
        ignored here (see :func:`pipeline_options`).

    Raises
    ------
    ConfigError
        Unknown name or target (the message lists the known ones), a key that is not a parameter of the
        optimizer, or an invalid value (checked at once when the optimizer has ``validate_params``).
    """
    if not isinstance(cfg, Mapping):
        raise ConfigError(f"The 'cfg' parameter of make_optimizer must be a mapping. Got {type(cfg).__name__}.")
    name = _resolve(cfg)
    factory = _REGISTRY[name].factory
    kwargs = {str(k): _plain(v) for k, v in cfg.items() if k not in PIPELINE_KEYS}
    accepted = _keywords(factory)
    if accepted is not None:
        for key in kwargs:
            if key not in accepted:
                raise unknown_setting("optimizer", key, kwargs[key], list(accepted) + list(PIPELINE_KEYS))
    try:
        optimizer = factory(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"optimizer ({name}): the config could not be applied: {exc}") from exc
    validate = getattr(optimizer, "validate_params", None)
    if callable(validate):
        try:
            validate()
        except SettingError as exc:  # the class's own key (GOA.alpha) as the config names it (optimizer.alpha)
            owner = f"{type(optimizer).__name__}."
            if not exc.key.startswith(owner):
                raise
            raise SettingError(f"optimizer.{exc.key[len(owner) :]}", exc.reason, exc.value, exc.hint) from None
    return optimizer


def pipeline_options(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """The workflow-level keys of an optimizer config, validated.

    Returns ``{"polish": bool, "objective": str, "bound_mm": float, "bound_deg": float,
    "stop_error": float | "auto" | None}`` (defaults: False, "nonlinear", 1.0, 0.1, None).
    """
    polish = check_bool(cfg.get("polish", False), "polish", "optimizer")
    objective = check_choice(cfg.get("objective", "nonlinear"), "objective", "optimizer", OBJECTIVE_KINDS)
    bound_mm = check_real(cfg.get("bound_mm", 1.0), "bound_mm", "optimizer", 0.0, low_open=True)
    bound_deg = check_real(cfg.get("bound_deg", 0.1), "bound_deg", "optimizer", 0.0, low_open=True)
    stop = cfg.get("stop_error", None)
    if stop is not None and stop != "auto":
        stop = check_real(stop, "stop_error", "optimizer", 0.0, low_open=True)
    return {"polish": polish, "objective": objective, "bound_mm": bound_mm, "bound_deg": bound_deg, "stop_error": stop}


@functools.cache
def _keywords(factory: Factory) -> tuple[str, ...] | None:
    """The keyword arguments ``factory`` takes (None: any, it has ``**kwargs``); read once per factory (the
    signature is the class's, a fit builds its optimizer every time)."""
    params = inspect.signature(factory).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return None
    return tuple(p for p, spec in params.items() if spec.kind is not inspect.Parameter.VAR_POSITIONAL)


def _plain(value: Any) -> Any:
    """OmegaConf containers to plain Python (constructor arguments are scalars, but be safe)."""
    if "omegaconf" not in sys.modules:  # no container can exist: skip the import machinery
        return value
    try:
        from omegaconf import Container, OmegaConf
    except ImportError:  # pragma: no cover - omegaconf comes with hydra-core
        return value
    if isinstance(value, Container):
        return OmegaConf.to_container(value, resolve=True)
    return value


register("goa", GOA, target="robocal.optimizers.goa.GOA")
register("igoa", ImprovedGOA, target="robocal.optimizers.goa.ImprovedGOA")
register("woa", WOA, target="robocal.optimizers.woa.WOA")
register("gn", GaussNewton, target="robocal.optimizers.gradient.GaussNewton")
register("lm", LevenbergMarquardt, target="robocal.optimizers.gradient.LevenbergMarquardt")
register("ipopt", Ipopt, target="robocal.optimizers.ipopt.Ipopt")
