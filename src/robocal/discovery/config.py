"""Settings of a discovery run (``conf/discovery/default.yaml``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from robocal.errors import ConfigError

#: Every effect the library knows, in the order candidates are built.
EFFECT_NAMES = ("compliance", "gear", "backlash", "thermal", "drift", "beta")


@dataclass(frozen=True)
class DiscoveryConfig:
    """How candidates are built and selected.

    noise_mm : tracker noise per coordinate (1 sigma): weights, chi² and the noise floor (raised to the noise the
        data show when the campaign allows a model-free estimate: see ``fit.noise`` of the calibration).
    noise_deg : orientation noise per axis (1 sigma) when the campaign has orientations.
    use_orientation : use measured orientations when present (``None`` = when present), as ``calibrate`` does.
    outliers, outlier_alpha : gross errors, as in the geometric calibration (``auto`` / ``off`` / file rows).
    effects : which effects of the library to try (subset of :data:`EFFECT_NAMES`).
    gear_harmonics : harmonics of the joint angle tried for the periodic gear error.
    thermal_components : principal components of the temperature log each parameter may follow (thermal).
    alpha : family-wise false-alarm rate of the nested F-test over the library (Bonferroni).
    min_excess_share : an accepted effect must remove at least this share of the excess chi² (chi² - dof)
        left by the current model; guards against a structured leftover passing by chance correlation.
    absorbed_tol : a candidate whose projected regressor keeps less than this share of its norm
        (per direction) is absorbed by the current model: unidentifiable, never chosen.
    cv_folds : folds (whole poses) of the cross-validation that must confirm an accepted effect; 0 = off.
    chi2_alpha : after the search, chi² above its (1 - chi2_alpha) quantile flags an unexplained residual.
    max_steps : at most this many effects are accepted.
    min_signal_std : a signal whose standard deviation (in its unit) is below this does not vary: skipped.
    fixed : calibration parameters held at nominal (shell patterns), as in the geometric calibration.
    rank_tol : rank tolerance of the identifiability analysis of the (extended) model.
    seed : seed of the cross-validation folds (and of the dictionary's resamples).
    dictionary : after the library, propose equations from the term dictionary (:mod:`robocal.discovery.dictionary`).
    dictionary_harmonics : harmonics 1..H of every joint angle; dictionary_product_harmonics : of the products of
        two joints' harmonics; dictionary_max_terms : terms per proposal; dictionary_max_proposals : proposals;
        dictionary_resamples / dictionary_stability : stability selection (half the poses per resample; a term
        must be chosen in this share of them).
    """

    noise_mm: float = 0.015
    noise_deg: float = 0.01
    use_orientation: bool | None = None
    outliers: str | tuple[int, ...] = "auto"
    outlier_alpha: float = 0.001
    effects: tuple[str, ...] = EFFECT_NAMES
    gear_harmonics: tuple[int, ...] = (1, 2)
    thermal_components: int = 2
    alpha: float = 0.001
    min_excess_share: float = 0.3
    absorbed_tol: float = 1e-3
    cv_folds: int = 5
    chi2_alpha: float = 0.001
    max_steps: int = 6
    min_signal_std: float = 1e-9
    fixed: tuple[str, ...] = ()
    rank_tol: float = 1e-6
    max_iter: int = 100
    seed: int = 0
    dictionary: bool = True
    dictionary_harmonics: int = 3
    dictionary_product_harmonics: int = 2
    dictionary_max_terms: int = 2
    dictionary_max_proposals: int = 2
    dictionary_resamples: int = 40
    dictionary_stability: float = 0.7

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> DiscoveryConfig:
        """Build from a mapping (a Hydra node); unknown keys and bad values are errors naming the key."""
        if cfg is None:
            return cls()
        data = dict(cfg)
        data.pop("report", None)
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown discovery setting(s) {unknown}; known: {sorted(known)}")
        for key in ("effects", "gear_harmonics", "fixed"):
            if key in data:
                data[key] = tuple(data[key] or ())
        if "outliers" in data or "outlier_alpha" in data:
            from robocal.identification.calibrate import CalibrationConfig

            sub = {k: data[k] for k in ("outliers", "outlier_alpha") if k in data}
            try:
                checked = CalibrationConfig.from_mapping(sub)
            except ConfigError as exc:
                raise ConfigError(str(exc).replace("calibration setting", "discovery setting")) from None
            data.update({k: getattr(checked, k) for k in sub})
        out = cls(**data)
        bad = [e for e in out.effects if e not in EFFECT_NAMES]
        if bad:
            raise ConfigError(f"The 'discovery.effects' setting names unknown effect(s) {bad}; known: {EFFECT_NAMES}")
        for name in ("noise_mm", "noise_deg", "alpha", "absorbed_tol", "chi2_alpha", "rank_tol"):
            if not float(getattr(out, name)) > 0:
                raise ConfigError(f"The 'discovery.{name}' setting must be > 0. Got {getattr(out, name)!r} instead.")
        if not 0.0 <= out.min_excess_share < 1.0:
            raise ConfigError(
                f"The 'discovery.min_excess_share' setting must be in [0, 1). Got {out.min_excess_share}."
            )
        if any(int(h) < 1 for h in out.gear_harmonics):
            raise ConfigError(
                f"The 'discovery.gear_harmonics' setting must hold integers >= 1. Got {out.gear_harmonics}."
            )
        if out.cv_folds == 1 or out.cv_folds < 0:
            raise ConfigError(f"The 'discovery.cv_folds' setting must be 0 (off) or >= 2. Got {out.cv_folds}.")
        if out.thermal_components < 1:
            raise ConfigError(f"The 'discovery.thermal_components' setting must be >= 1. Got {out.thermal_components}.")
        for key in (
            "dictionary_harmonics",
            "dictionary_product_harmonics",
            "dictionary_max_terms",
            "dictionary_resamples",
        ):
            if int(getattr(out, key)) < 1:
                raise ConfigError(f"The 'discovery.{key}' setting must be >= 1. Got {getattr(out, key)!r}.")
        if out.dictionary_max_proposals < 0:
            raise ConfigError(
                f"The 'discovery.dictionary_max_proposals' setting must be >= 0. Got {out.dictionary_max_proposals}."
            )
        if not 0.5 <= out.dictionary_stability <= 1.0:
            raise ConfigError(
                f"The 'discovery.dictionary_stability' setting must be in [0.5, 1]. Got {out.dictionary_stability}."
            )
        if out.max_steps < 0:
            raise ConfigError(f"The 'discovery.max_steps' setting must be >= 0. Got {out.max_steps}.")
        return out

    def to_dict(self) -> dict[str, Any]:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}
