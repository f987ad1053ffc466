"""Every fit goes through the one optimizer protocol (issue 32): :func:`robocal.optimizers.least_squares.
least_squares` states a weighted least squares over a subset of variables as a Problem for the registered gradient
optimizer, and gives the same bits as the least-squares core called directly (what the rigid fit, IRLS, compliance,
decoupling, discovery's joint refit and the twin's truth fit did before); no module outside the optimizer package
calls the core itself."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from robocal.optimizers.gradient import LevenbergMarquardt
from robocal.optimizers.least_squares import least_squares
from robocal.optimizers.registry import register
from robocal.optimizers.solver import levenberg_marquardt

SRC = Path(__file__).resolve().parents[2] / "src" / "robocal"
#: the optimizer package: the core itself and the optimizers that wrap it
HOME = SRC / "optimizers"


def _problem(seed: int, m: int = 40, n: int = 6):
    """A small nonlinear least squares (exponential decays) with its analytic Jacobian."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 3.0, m)
    x_true = rng.uniform(0.5, 1.5, n)

    def model(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = n // 2
        a, b = x[:k], x[k:]
        e = np.exp(-np.outer(t, b))  # (m, k)
        y = e @ a
        J = np.hstack([e, -(t[:, None] * e) * a])
        return y, J

    y_obs = model(x_true)[0] + 0.01 * rng.standard_normal(m)

    def fun(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y, J = model(x)
        return y - y_obs, J

    return fun, x_true * rng.uniform(0.8, 1.2, n), rng


CASES = [
    # (free, weights, settings): every column or a subset; unit, scalar, per-residual weights with zeros
    ("all", "unit", {}),
    ("subset", "unit", {"method": "gn", "max_iter": 20, "ftol": 1e-15, "xtol": 1e-12}),
    ("subset", "rows", {"lam0": 0.0, "max_iter": 30}),
    ("all", "zeros", {"max_iter": 100, "ftol": 1e-14, "xtol": 1e-12, "lam0": 0.0}),
    ("subset", "scalar", {"max_iter": 50}),
]


@pytest.mark.parametrize(("which", "weighting", "settings"), CASES)
def test_the_protocol_gives_the_cores_bits(which: str, weighting: str, settings: dict) -> None:
    fun, x0, rng = _problem(len(which) + len(weighting))
    n = x0.size
    free = np.arange(n) if which == "all" else np.array([0, 2, 3, 5])
    weights: np.ndarray | float = {
        "unit": 1.0,
        "scalar": 3.0,
        "rows": rng.uniform(0.5, 2.0, 40),
        "zeros": np.where(np.arange(40) % 7 == 0, 0.0, 2.0),
    }[weighting]
    old = levenberg_marquardt(fun, x0, free, weights, **settings)
    new = least_squares(fun, x0, free, weights, **settings)
    assert old.nit > 0 and old.status >= 0  # a real fit, not a start that stops at once
    for field in ("x", "residual", "jacobian", "covariance"):
        np.testing.assert_array_equal(getattr(new, field), getattr(old, field), err_msg=field)  # bit for bit
    for field in ("cost", "chi2", "ndata", "status", "nit", "nfev", "njev", "method", "history", "dof"):
        assert getattr(new, field) == getattr(old, field), field
    np.testing.assert_array_equal(new.varied, free)


def test_the_solver_is_the_registered_one() -> None:
    """One place owns the solver choice: a plugin registered as ``lm`` runs these fits too."""
    calls = []

    class Counting(LevenbergMarquardt):
        def minimize(self, problem):  # type: ignore[no-untyped-def]
            calls.append(problem.n)
            return super().minimize(problem)

    register("lm", Counting, overwrite=True)
    try:
        fun, x0, _ = _problem(3)
        least_squares(fun, x0, np.array([1, 4]))
    finally:
        register("lm", LevenbergMarquardt, overwrite=True)
    assert calls == [2]


def test_no_fit_outside_the_optimizers_calls_the_core() -> None:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if HOME in path.parents:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            f = node.func if isinstance(node, ast.Call) else None
            name = f.id if isinstance(f, ast.Name) else (f.attr if isinstance(f, ast.Attribute) else None)
            if name == "levenberg_marquardt":
                found.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert not found, "levenberg_marquardt called past the optimizer protocol (use least_squares):\n" + "\n".join(found)
