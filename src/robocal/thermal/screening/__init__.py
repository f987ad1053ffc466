"""Sensitivity screening of the kinematic parameters for thermal compensation (Guo et al. 2026, section 3.4).

Only some kinematic parameters drift measurably with temperature, and only some of those move the tool enough to
matter. The screening ranks every parameter of the chain by its *influence* on the tool pose at a temperature
state and keeps the ones worth identifying and compensating (fewer parameters, fewer poses per warm-up state).

1. **Sensitivity** (eq. 22-25). ``n_configs`` joint configurations uniform in the joint ranges (table 3); each
   parameter is perturbed on its own by ``+/- delta`` (``angle_step_deg`` = 0.01 deg for angles,
   ``length_step_mm`` = 0.1 mm for lengths), the others held at nominal. Per configuration, sign and tool point:

   - position error ``dP_pos = |p_s - p_0|`` (mm, eq. 23), ``p`` the tool point(s) ``tool_mm`` (flange frame);
   - orientation error ``dP_ori = || R_s R_0^T - I ||_F`` (eq. 24; dimensionless, ~ sqrt(2) x the angle in rad);
   - total ``dP_total = dP_pos + dP_ori`` (eq. 25), and ``E_mean`` its mean over configurations, signs and points.

   The linear prediction ``|J_eta[:, :, k]| * delta`` from the error Jacobian (eq. 22) is reported beside it
   (``jacobian_mean_position_mm``): the two agree for steps this small, which checks both.
2. **Influence at temperature T** (eq. 26-27). With the parameter drift ``d_eta_o(T)`` identified at a
   temperature state (the thermal fit's per-state solution, e.g. at thermal equilibrium):
   ``P_o(T) = d_eta_o(T) / delta_eta_o`` and ``H = E_mean * P_o(T)`` (signed, as in table 4; "mm" with the small
   Frobenius part of eq. 25 added).
3. **Selection**: a configurable rule on the score ``|H|`` (``threshold`` on ``|H|``; ``share``: the fewest
   parameters holding a share of ``sum |H|``; ``top_k``; ``relative`` to the largest ``|H|``), then ``include`` /
   ``exclude`` name patterns. Without any drift the score is ``E_mean`` (pure sensitivity) and the result says so.

:func:`screen` computes everything (vectorised: one chain propagation over a population of ``2 x P`` perturbed
parameter vectors); :func:`screening_figures` gives the equivalents of fig. 9 and table 4; :func:`add_to_report`
writes the HTML section; :func:`load_drift` reads a drift file. Internally lengths are mm and angles rad; the
config (``conf/screen/default.yaml``) gives steps and ``drift`` in mm and degrees.
"""

from robocal.thermal.screening.compute import sample_configurations, screen
from robocal.thermal.screening.config import (
    COLUMNS,
    DRIFT_STATES,
    FORMAT,
    RULES,
    ScreeningConfig,
    SelectionConfig,
    load_drift,
    load_drift_stderr,
)
from robocal.thermal.screening.report import (
    FIGURE_FILES,
    add_to_report,
    save_screening_figures,
    screening_figures,
    write_screening,
)
from robocal.thermal.screening.result import ScreeningResult

__all__ = [
    "COLUMNS",
    "DRIFT_STATES",
    "FIGURE_FILES",
    "FORMAT",
    "RULES",
    "ScreeningConfig",
    "ScreeningResult",
    "SelectionConfig",
    "add_to_report",
    "load_drift",
    "load_drift_stderr",
    "sample_configurations",
    "save_screening_figures",
    "screen",
    "screening_figures",
    "write_screening",
]
