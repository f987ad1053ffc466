"""The geometric calibration as an optimizer :class:`~robocal.optimizers.protocol.Problem`.

:func:`calibration_problem` turns a :class:`~robocal.identification.model.CalibrationModel`, its data, a
start ``x_init`` (full parameter vector: nominal kinematics, frames from the registration) and the free
(identifiable) parameter indices into a Problem over the free parameters only, the others held at
``x_init``:

* ``objective="nonlinear"``: position residuals of the full model, predicted - measured (mm); fitness
  ``rms3d`` (RMS 3-D position error, mm). ``batch_residuals`` is the fast population kernel
  (:class:`robocal.optimizers.fastfk.PopulationPositions`); ``residuals``/``jacobian`` come from the model
  (analytic); ``symbolic`` is the same residual built in CasADi (:class:`CalibrationSymbolic`) for Ipopt.
* ``objective="linearized"``: the thermal paper's error model ``dP = J dEta`` linearised at ``x_init``:
  residual ``J (z - z_init) - dP`` with ``dP = measured - predicted(x_init)``; fitness ``mean3d``, i.e. eq. 9
  (``sum_l |dP_l - J_l dEta|``) divided by the number of poses. One matrix product per population.

Bounds: ``x_init ± bound_mm`` for lengths (mm) and ``± bound_deg`` for angles, per variable. Variable
scale (used by Ipopt): ``1 / |J_k|``, the change of each parameter that moves the residual vector by 1 mm at
``x_init`` (the column scaling Gauss-Newton uses), so that the scaled problem is well conditioned.

:func:`least_squares_problem` is the calibration's own least squares as a Problem (what the gradient optimizers
``lm`` and ``gn`` solve in every geometric fit): the whitened residuals of every row (positions and, with
orientation data, rotations) over the free parameters of a :class:`~robocal.calibration.
CalibrationStart`, the rows left out as gross errors weighted zero, unbounded.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.calibration.start import CalibrationStart
from robocal.errors import ConfigError
from robocal.identification.identifiability import ParameterSpec
from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics.chain import FIXED, Chain, step
from robocal.metrics import ErrorStats
from robocal.optimizers.fastfk import PopulationPositions
from robocal.optimizers.least_squares import Whitened
from robocal.optimizers.protocol import Problem, check_real

__all__ = [
    "OBJECTIVE_FITNESS",
    "CalibrationSearch",
    "CalibrationSymbolic",
    "WhitenedResiduals",
    "calibration_problem",
    "chain_key",
    "least_squares_problem",
]

#: Fitness used for each objective kind of the optimizer config.
OBJECTIVE_FITNESS = {"nonlinear": "rms3d", "linearized": "mean3d"}


def chain_key(chain: Chain) -> str:
    """A short hash identifying a compiled chain (element kinds, nominal values, joints, parameters)."""
    h = hashlib.sha1()
    h.update(np.asarray(chain.kinds, dtype=np.int64).tobytes())
    h.update(np.asarray(chain.nominal, dtype=float).tobytes())
    h.update(np.asarray(chain.joint, dtype=np.int64).tobytes())
    h.update(np.asarray(chain.param, dtype=np.int64).tobytes())
    for T in chain.fixed:
        if T is not None:
            h.update(np.asarray(T, dtype=float).tobytes())
    h.update(str(chain.n_joints).encode())
    return h.hexdigest()[:16]


def position_data(data: FitData) -> FitData:
    """``data`` without orientations (the population objectives use positions only)."""
    return FitData(
        q=data.q, p_mm=data.p_mm, target_index=data.target_index, R_meas=None, station_index=data.station_index
    )


# --------------------------------------------------------------------------------------------------------
# symbolic (CasADi) forward kinematics: robocal.kinematics.chain.step on CasADi expressions
# --------------------------------------------------------------------------------------------------------

_FUNCTIONS: dict[tuple[Any, ...], Any] = {}


def _casadi_point_function(model: CalibrationModel) -> Any:
    """CasADi ``p(x (n,), q (nj,), T0 (3, 4), sel (K,)) -> (3,)``: one target point in the tracker frame."""
    import casadi as ca

    chain = model.full_chain
    K = len(model.target_names)
    xs = ca.SX.sym("x", model.n)
    q = ca.SX.sym("q", chain.n_joints)
    T0 = ca.SX.sym("T0", 3, 4)
    sel = ca.SX.sym("sel", K)
    frame = (T0[:, 0], T0[:, 1], T0[:, 2], T0[:, 3])
    for e, kind in enumerate(chain.kinds):
        v: Any = float(chain.nominal[e])
        if kind != FIXED:
            if chain.joint[e] >= 0:
                v = v + q[int(chain.joint[e])]
            if chain.param[e] >= 0:
                v = v + xs[int(chain.param[e])]
        frame = step(kind, v, frame, chain.fixed[e], ca.cos, ca.sin)  # the same element code as propagate
    X, Y, Z, O = frame
    tools = ca.reshape(xs[model.n_chain : model.n_chain + 3 * K], 3, K)
    t = ca.mtimes(tools, sel)
    p = O + X * t[0] + Y * t[1] + Z * t[2]
    return ca.Function("target_point", [xs, q, T0, sel], [p])


@dataclass
class CalibrationSymbolic:
    """The nonlinear position residuals of a calibration in CasADi, for :class:`robocal.optimizers.ipopt.Ipopt`.

    ``function()`` is ``r(z, p)``: ``z`` the free parameters, ``p`` = [full x of the fixed values, T_ref (3x4),
    joint angles, target selectors, measured positions]. Cached per ``key`` = (chain, targets, poses, free
    set), so a second calibration of the same robot and campaign size reuses the graph.
    """

    model: CalibrationModel
    data: FitData
    x_base: np.ndarray
    free: np.ndarray
    key: tuple[Any, ...] = field(init=False)

    def __post_init__(self) -> None:
        self.key = (
            "calibration-positions",
            chain_key(self.model.full_chain),
            self.model.n,
            len(self.model.target_names),
            self.model.n_chain,
            self.data.m,
            tuple(int(i) for i in self.free),
        )

    def function(self) -> Any:
        import casadi as ca

        if self.key in _FUNCTIONS:
            return _FUNCTIONS[self.key]
        model, m, k, n = self.model, self.data.m, len(self.free), self.model.n
        nj, K = model.chain.n_joints, len(model.target_names)
        point = _casadi_point_function(model).map(m, "serial")
        z = ca.MX.sym("z", k)
        n_p = n + 12 + nj * m + K * m + 3 * m
        p = ca.MX.sym("p", n_p)
        S = np.zeros((n, k))
        S[self.free, np.arange(k)] = 1.0
        x_full = p[:n] + ca.mtimes(ca.DM(S), z)
        o = n
        T0 = ca.reshape(p[o : o + 12], 3, 4)
        o += 12
        Q = ca.reshape(p[o : o + nj * m], nj, m)
        o += nj * m
        SEL = ca.reshape(p[o : o + K * m], K, m)
        o += K * m
        Pm = ca.reshape(p[o : o + 3 * m], 3, m)
        pred = point(ca.repmat(x_full, 1, m), Q, ca.repmat(T0, 1, m), SEL)
        r = ca.vec(pred - Pm)  # column-major (3, m): [x1, y1, z1, x2, ...] as the model's residuals
        f = ca.Function("calibration_residuals", [z, p], [r])
        _FUNCTIONS[self.key] = f
        return f

    def parameters(self) -> np.ndarray:
        model, data = self.model, self.data
        K = len(model.target_names)
        sel = np.zeros((K, data.m))
        sel[data.target_index, np.arange(data.m)] = 1.0
        x_fixed = np.asarray(self.x_base, dtype=float).copy()
        x_fixed[self.free] = 0.0  # the free entries come from z
        return np.concatenate(
            [
                x_fixed,
                np.asarray(model.T_ref, dtype=float)[:3, :4].ravel(order="F"),
                np.asarray(data.q, dtype=float).T.ravel(order="F"),
                sel.ravel(order="F"),
                np.asarray(data.p_mm, dtype=float).T.ravel(order="F"),
            ]
        )


# --------------------------------------------------------------------------------------------------------
# the search over the free parameters
# --------------------------------------------------------------------------------------------------------


@dataclass
class CalibrationSearch:
    """Maps the free parameters ``z (k,)`` (or a population ``(pop, k)``) to the full vector ``x (n,)``."""

    model: CalibrationModel
    data: FitData
    x_init: np.ndarray
    free: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray
    positions: Any = None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.model.names[i] for i in self.free)

    @property
    def z_init(self) -> np.ndarray:
        return self.x_init[self.free].copy()

    def full(self, z: np.ndarray) -> np.ndarray:
        """Full parameter vector(s) with the free entries replaced by ``z``."""
        z = np.asarray(z, dtype=float)
        if z.ndim == 1:
            x = self.x_init.copy()
            x[self.free] = z
            return x
        X = np.tile(self.x_init, (z.shape[0], 1))
        X[:, self.free] = z
        return X

    def nonlinear_batch(self, Z: np.ndarray) -> np.ndarray:
        return self.positions(self.full(Z))

    def nonlinear_residuals(self, z: np.ndarray) -> np.ndarray:
        return self.model.residuals(self.full(z), self.data)

    def nonlinear_jacobian(self, z: np.ndarray) -> np.ndarray:
        return self.model.residuals_and_jacobian(self.full(z), self.data)[1][:, self.free]

    def rms_mm(self, z: np.ndarray) -> float:
        """RMS 3-D position error (mm) of the nonlinear model at the free parameters ``z``."""
        return ErrorStats.of(self.nonlinear_residuals(z).reshape(-1, 3)).rms_mm


def search_bounds(
    model: CalibrationModel, free: np.ndarray, x_init: np.ndarray, bound_mm: float, bound_deg: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower, upper bounds and scale (half-widths) of the free parameters around ``x_init``."""
    bound_mm = check_real(bound_mm, "bound_mm", "the optimizer config", 0.0, low_open=True)
    bound_deg = check_real(bound_deg, "bound_deg", "the optimizer config", 0.0, low_open=True)
    box = ParameterSpec.of(model).around(x_init, bound_mm, float(np.deg2rad(bound_deg)))
    assert box.lower is not None and box.upper is not None and box.scale is not None
    return box.lower[free], box.upper[free], box.scale[free]


def calibration_problem(
    model: CalibrationModel,
    data: FitData,
    x_init: np.ndarray,
    free: np.ndarray | list[int],
    *,
    objective: str = "nonlinear",
    bound_mm: float = 1.0,
    bound_deg: float = 0.1,
    target: float | None = None,
    max_iter: int = 200,
    seed: int = 0,
    bounded: bool = True,
    backend: str = "auto",
) -> tuple[Problem, CalibrationSearch]:
    """The Problem over the free parameters and the :class:`CalibrationSearch` that maps back to ``x``.

    Parameters
    ----------
    objective : {"nonlinear", "linearized"}
    bound_mm, bound_deg : float
        Half-width of the search box around ``x_init`` for lengths (mm) and angles (deg).
    target : float, optional
        Stop when the best fitness (mm) is below it.
    bounded : bool
        False gives infinite bounds (the gradient methods' unconstrained least squares); the scale is kept.
    backend : str
        Of the population kernel, see :class:`~robocal.optimizers.fastfk.PopulationPositions`.
    """
    if objective not in OBJECTIVE_FITNESS:
        raise ConfigError(
            f"The 'objective' key of the optimizer config must be one of {list(OBJECTIVE_FITNESS)}. "
            f"Got {objective!r} instead."
        )
    free = np.asarray(free, dtype=int)
    if free.size == 0:
        raise ConfigError("The calibration has no free parameter to search (every parameter fixed or eliminated).")
    x_init = np.asarray(x_init, dtype=float).copy()
    pdata = position_data(data)
    free_pos = np.array([i for i in free if model.kinds[i] != "tool_rot"], dtype=int)  # positions only
    lower, upper, _ = search_bounds(model, free_pos, x_init, bound_mm, bound_deg)
    r0, J = model.residuals_and_jacobian(x_init, pdata)
    norms = np.linalg.norm(J[:, free_pos], axis=0)
    # typical magnitude: the change that moves the residual vector by 1 mm (what Gauss-Newton scales by)
    scale = 1.0 / np.where(norms > 0, norms, 1.0)
    try:
        if model.n_stations > 1:  # the compiled kernel folds one tracker frame
            raise ValueError("several tracker stations")
        positions: Any = PopulationPositions(model, pdata, backend=backend)
    except ValueError:  # a chain the kernel does not handle: the model's own (slower) method
        positions = lambda X: model.batch_position_residuals(X, pdata)  # noqa: E731
    search = CalibrationSearch(model, pdata, x_init, free_pos, lower, upper, scale, positions)
    if not bounded:
        lower, upper = np.full(free_pos.size, -np.inf), np.full(free_pos.size, np.inf)
    common: dict[str, Any] = {
        "n": int(free_pos.size),
        "lower": lower,
        "upper": upper,
        "x0": search.z_init,
        "scale": scale,
        "names": search.names,
        "objective": OBJECTIVE_FITNESS[objective],
        "target": target,
        "max_iter": max_iter,
        "seed": seed,
    }
    if objective == "nonlinear":
        problem = Problem(
            **common,
            residuals=search.nonlinear_residuals,
            jacobian=search.nonlinear_jacobian,
            batch_residuals=search.nonlinear_batch,
            # the CasADi mirror folds one tracker frame: several stations have no symbolic form (Ipopt says so)
            symbolic=CalibrationSymbolic(model, pdata, x_init, free_pos) if model.n_stations == 1 else None,
        )
        return problem, search
    J0 = np.ascontiguousarray(J[:, free_pos])
    z0 = search.z_init
    b = r0 - J0 @ z0  # r(z) = r0 + J0 (z - z0) = J0 z + b

    def linear_batch(Z: np.ndarray) -> np.ndarray:
        out = Z @ J0.T
        out += b
        return out

    problem = Problem(
        **common,
        residuals=lambda z: J0 @ z + b,
        jacobian=lambda z: J0,
        batch_residuals=linear_batch,
    )
    return problem, search


# --------------------------------------------------------------------------------------------------------
# the calibration's least squares (the gradient optimizers' Problem)
# --------------------------------------------------------------------------------------------------------


class WhitenedResiduals(Whitened):
    """The whitened residuals ``w r(x)`` and Jacobian ``w J(x)`` of a started calibration on its free parameters
    ``z`` (the others held at ``x_from``), ``w`` the noise weights with the rows left out weighted zero; with a
    prior (a thin campaign, :mod:`robocal.identification.thin`) its rows ``w_p (z - z_init)`` follow the data's.
    The last point's pair is kept (:class:`~robocal.optimizers.least_squares.Whitened`; at ``x_init`` no model
    evaluation: the start's).
    """

    def __init__(self, start: CalibrationStart, x_from: np.ndarray, kept: np.ndarray) -> None:
        weights = start.weights if kept.all() else start.weights * kept[start.rows]
        super().__init__(start.fun, x_from, start.free, weights)
        # a thin campaign's prior (robocal.identification.thin.Prior): rows w (z - z_init) after the data's
        prior = start.prior
        self.prior_w = None if prior is None else np.asarray(prior.rows(start.free), dtype=float)
        self.z_center = np.asarray(start.x_init, dtype=float)[start.free]

    @property
    def x_from(self) -> np.ndarray:
        """Where the fit starts (the entries not fitted stay there)."""
        return self.x0

    @property
    def n_prior(self) -> int:
        """The prior's rows at the end of the residuals (0 without a prior)."""
        return 0 if self.prior_w is None else int(self.prior_w.size)

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, J = super().evaluate(z)
        if self.prior_w is None:
            return r, J
        pw = self.prior_w
        return np.concatenate([r, pw * (np.asarray(z, dtype=float) - self.z_center)]), np.vstack([J, np.diag(pw)])


def least_squares_problem(
    start: CalibrationStart, x_from: np.ndarray, kept: np.ndarray
) -> tuple[Problem, WhitenedResiduals]:
    """The calibration's least squares from ``x_from`` on the ``kept`` rows as a Problem over the free
    parameters (objective ``sse``: the sum of squared whitened residuals, χ²; no bounds), and the
    :class:`WhitenedResiduals` that map its point back to the full vector."""
    if start.free.size == 0:
        raise ConfigError("The calibration has no free parameter to fit (every parameter fixed or eliminated).")
    wr = WhitenedResiduals(start, x_from, kept)
    names = start.model.names
    problem = Problem(
        n=int(start.free.size),
        lower=np.full(start.free.size, -np.inf),
        upper=np.full(start.free.size, np.inf),
        x0=wr.x_from[start.free],
        names=tuple(names[i] for i in start.free),
        residuals=wr.residuals,
        jacobian=wr.jacobian,
        objective="sse",
    )
    return problem, wr
