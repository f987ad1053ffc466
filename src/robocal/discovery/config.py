"""Settings of a discovery run: their defaults are ``default.yaml`` beside this module, defined once.

That file is also the pipeline's ``discovery`` group (``conf/config.yaml`` puts ``pkg://robocal`` on Hydra's search
path), so ``robocal discover``, ``robocal.discover`` and the ``discover`` stage start from the same settings."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import yaml

from robocal.calibration.config import data_rows, outlier_rule
from robocal.config import parse, setting

#: Every effect the library knows, in the order candidates are built.
EFFECT_NAMES = (
    "compliance",
    "gear",
    "backlash",
    "thermal",
    "drift",
    "regap",
    "air",
    "scale",
    "beta",
    "transmission",
    "weight",
    "signal",
    "session",
)


#: The one definition of the defaults (with why each value), read by :class:`DiscoveryConfig` and by Hydra.
DEFAULTS_FILE = Path(__file__).with_name("default.yaml")
_D: dict[str, Any] = yaml.safe_load(DEFAULTS_FILE.read_text(encoding="utf-8"))


def _tuple(key: str) -> tuple[Any, ...]:
    return tuple(_D[key])


@dataclass(frozen=True)
class DiscoveryConfig:
    """How candidates are built and selected.

    noise_mm : tracker noise per coordinate (1 sigma): weights, chi² and the noise floor (raised to the noise the
        data show when the campaign allows a model-free estimate: see ``fit.noise`` of the calibration).
    noise_deg : orientation noise per axis (1 sigma) when the campaign has orientations.
    use_orientation : use measured orientations when present (``None`` = when present), as ``calibrate`` does.
    outliers, outlier_alpha : gross errors, as in the geometric calibration (``auto`` / ``off`` / file rows).
    outlier_screen_rows : with ``outliers: auto``, a campaign of more calibration rows than this is first searched
        on a pose-grouped sample of this many rows, only to find the gross errors (the search on every kept row
        follows); 0: never.
    effects : which effects of the library to try (subset of :data:`EFFECT_NAMES`); ``signal``: every logged signal
        (a numeric column of the campaign beyond the contract) as a driver (:mod:`robocal.discovery.logged`);
        ``session``: in a campaign of several sessions (tracker stations), a tool re-seated in each session.
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
    transmission_orders : Fourier orders (harmonics 1..K per revolution) tried for the gear transmission error of
        each joint (:mod:`robocal.discovery.physics`); transmission_prior_deg : prior standard deviations per
        coefficient tried (ridge); transmission_gap_deg / transmission_taper_deg : visits closer than the gap make
        one covered interval, and the effect falls to zero over the taper outside the covered angles;
        transmission_min_visits : the windows tried (the cross-validation picks): covered intervals of at least
        this many distinct angles (1: every visit; 2: a joint angle only one pose saw, far from the others, is
        outside the window, the error not applied there); with several values that give other windows the first
        search runs with each, the lower cross-validated error kept (``discovery.json`` ``transmission_window``).
    registration_gap_h : a pause in the measurements longer than this offers a fresh tracker registration after it
        (``regap``, measurement side).
    compliance_prior_deg : the physical prior on the deflection under the arm's own weight (RMS over the poses,
        deg) when the link masses are unknown (the ``weight`` effect).
    cv_alpha : false-discovery control of the cross-validated selection (:mod:`robocal.discovery.grow`): a
        candidate's held-out gain must pass a one-sided paired t-test over poses at cv_alpha / (candidates tried).
    min_held_out_gain : an effect earns its place when the pose-grouped cross-validated RMS error as fitted
        (positions and, with a 6-DoF probe, orientations, whitened) without it exceeds the model's by more than
        this share (0.001: 0.1 %); the others are dropped, also the residual layer's joints (the held-out check,
        after the parametric model and after the layer).
    grow_max_steps : at most this many effects are added by the cross-validated selection.
    grow_geometry : ``joint`` (the geometry is refitted with the effects the selection adds), ``frozen`` (held
        at the model found before the selection: where a windowed effect is off, the model is that one) or
        ``auto`` (both searched on the first search's rows; frozen kept only when its pose-grouped cross-validated
        error is lower by the paired test per pose group at ``cv_alpha``, else joint; both figures and the test in
        ``discovery.json`` ``grow_geometry``; about twice the search's time).
    layer : offer the residual layer after the parametric model (kernel ridge on the joint angles, accepted only
        when the cross-validated selection says it helps); layer_centres : kernel centres (k-means of the
        calibration poses); layer_length_deg : kernel length scales tried; layer_prior_deg : prior widths tried.
    seed : seed of the cross-validation folds (and of the dictionary's resamples).
    dictionary : after the library, propose equations from the term dictionary (:mod:`robocal.discovery.dictionary`).
    dictionary_harmonics : harmonics 1..H of every joint angle; dictionary_product_harmonics : of the products of
        two joints' harmonics; dictionary_max_terms : terms per proposal; dictionary_max_proposals : proposals;
        dictionary_resamples / dictionary_stability : stability selection (half the poses per resample; a term
        must be chosen in this share of them).
    """

    noise_mm: float = setting(_D["noise_mm"], gt=0)
    noise_deg: float = setting(_D["noise_deg"], gt=0)
    use_orientation: bool | None = _D["use_orientation"]
    outliers: str | tuple[int, ...] = setting(
        _D["outliers"], choices=("auto", "off"), convert=outlier_rule, check=data_rows
    )
    outlier_alpha: float = setting(_D["outlier_alpha"], gt=0, lt=1)
    outlier_screen_rows: int = setting(_D["outlier_screen_rows"], ge=0)
    effects: tuple[str, ...] = setting(_tuple("effects"), choices=EFFECT_NAMES)
    gear_harmonics: tuple[int, ...] = setting(_tuple("gear_harmonics"), ge=1)
    thermal_components: int = setting(_D["thermal_components"], ge=1)
    alpha: float = setting(_D["alpha"], gt=0)
    min_excess_share: float = setting(_D["min_excess_share"], ge=0, lt=1)
    absorbed_tol: float = setting(_D["absorbed_tol"], gt=0)
    cv_folds: int = setting(_D["cv_folds"], ge=0, check=lambda k: "must be 0 (off) or >= 2" if k == 1 else None)
    chi2_alpha: float = setting(_D["chi2_alpha"], gt=0)
    max_steps: int = setting(_D["max_steps"], ge=0)
    min_signal_std: float = _D["min_signal_std"]
    fixed: tuple[str, ...] = _tuple("fixed")
    rank_tol: float = setting(_D["rank_tol"], gt=0)
    max_iter: int = _D["max_iter"]
    transmission_orders: tuple[int, ...] = setting(_tuple("transmission_orders"), ge=1)
    transmission_prior_deg: tuple[float, ...] = setting(_tuple("transmission_prior_deg"), gt=0)
    transmission_gap_deg: float = setting(_D["transmission_gap_deg"], gt=0)
    transmission_taper_deg: float = setting(_D["transmission_taper_deg"], ge=0)
    transmission_min_visits: tuple[int, ...] = setting(_tuple("transmission_min_visits"), ge=1)
    compliance_prior_deg: float = setting(_D["compliance_prior_deg"], gt=0)
    registration_gap_h: float = setting(_D["registration_gap_h"], gt=0)
    cv_alpha: float = setting(_D["cv_alpha"], gt=0, lt=1)
    min_held_out_gain: float = setting(_D["min_held_out_gain"], ge=0, lt=1)
    grow_max_steps: int = setting(_D["grow_max_steps"], ge=0)
    grow_geometry: str = setting(_D["grow_geometry"], choices=("joint", "frozen", "auto"))
    geometry_prior: str = setting(_D["geometry_prior"], choices=("auto", "calibration", "none"))
    counterbalance: str = setting(_D["counterbalance"], choices=("auto", "on", "off"))
    layer: bool = _D["layer"]
    layer_centres: int = setting(_D["layer_centres"], ge=4)
    layer_length_deg: tuple[float, ...] = setting(_tuple("layer_length_deg"), gt=0)
    layer_prior_deg: tuple[float, ...] = setting(_tuple("layer_prior_deg"), gt=0)
    seed: int = _D["seed"]
    dictionary: bool = _D["dictionary"]
    dictionary_harmonics: int = setting(_D["dictionary_harmonics"], ge=1)
    dictionary_product_harmonics: int = setting(_D["dictionary_product_harmonics"], ge=1)
    dictionary_max_terms: int = setting(_D["dictionary_max_terms"], ge=1)
    dictionary_max_proposals: int = setting(_D["dictionary_max_proposals"], ge=0)
    dictionary_resamples: int = setting(_D["dictionary_resamples"], ge=1)
    dictionary_stability: float = setting(_D["dictionary_stability"], ge=0.5, le=1)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> DiscoveryConfig:
        """Build from a mapping (a Hydra node, YAML, ``key=value`` overrides); errors name the key. ``report``
        is the command's switch, not a discovery setting."""
        return parse(cls, cfg, "discovery", ignore=("report",))

    def to_dict(self) -> dict[str, Any]:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}
