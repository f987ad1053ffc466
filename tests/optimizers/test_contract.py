"""The optimizer protocol's contract, run against every registered optimizer (gn, lm, ipopt, goa, igoa, woa).

The population methods have their own, longer contract in ``test_metaheuristics.py`` (bounds at every iteration,
batch calls, stopping at a target ...); this one is what every optimizer promises, whatever its family: a
:class:`Problem` in, a complete :class:`FitResult` out, the minimum of a least-squares problem found, the same
result for the same seed, built from its config file, bad input refused naming the parameter.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from robocal.errors import ConfigError
from robocal.optimizers import (
    STATUS_MESSAGES,
    FitResult,
    Optimizer,
    Problem,
    evaluate,
    make_optimizer,
    registered,
)

CONF = Path(__file__).resolve().parents[2] / "conf" / "optimizer"

#: the minimum (0) of the shifted sphere ``|x - C|²``, inside the box [-5, 5]^6, away from the start (0)
C = np.linspace(-2.0, 3.0, 6)


class SphereSymbolic:
    """The residual ``r(z, p) = z - p`` in CasADi, ``p = C`` (what Ipopt reads from ``problem.symbolic``)."""

    key = ("contract-sphere", 6)

    def function(self):
        import casadi as ca

        z, p = ca.MX.sym("z", 6), ca.MX.sym("p", 6)
        return ca.Function("sphere", [z, p], [z - p])

    def parameters(self) -> np.ndarray:
        return C.copy()


def least_squares_problem(seed: int = 0) -> Problem:
    """Every form an optimizer may need: residuals + Jacobian (gradient), batch (population), symbolic (Ipopt)."""
    return Problem(
        n=6,
        lower=-5.0,
        upper=5.0,
        x0=np.zeros(6),
        residuals=lambda x: x - C,
        jacobian=lambda x: np.eye(6),
        batch_residuals=lambda X: X - C,
        symbolic=SphereSymbolic(),
        names=tuple(f"p{i}" for i in range(6)),
        seed=seed,
        max_iter=100,
    )


#: name -> (small budget that keeps the test fast, the fitness the budget must reach).
#: The gradient and interior-point methods solve this linear least squares exactly (cost ~ 1e-20: rounding);
#: the population methods reach ~1e-3 (GOA, improved GOA) and ~1 (WOA stalls on shifted problems, see
#: test_metaheuristics.py) with 60 x 100 evaluations; each bound is ~5x what they reach over seeds 0-4.
CONTRACT: dict[str, tuple[dict, float]] = {
    "gn": ({}, 1e-12),
    "lm": ({}, 1e-12),
    "ipopt": ({}, 1e-12),
    "goa": ({"population": 60, "max_iter": 100}, 0.1),
    "igoa": ({"population": 60, "max_iter": 100}, 0.05),
    "woa": ({"population": 60, "max_iter": 100}, 5.0),
}


def make(name: str) -> Optimizer:
    return make_optimizer({"name": name, **CONTRACT[name][0]})


def test_every_registered_optimizer_is_under_the_contract():
    assert sorted(registered()) == sorted(CONTRACT)
    assert set(registered("gradient")) | set(registered("population")) | {"ipopt"} == set(CONTRACT)


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_minimizes_a_least_squares_problem(name):
    res = make(name).minimize(least_squares_problem())
    assert res.cost < CONTRACT[name][1], res.cost


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_result_fields_complete(name):
    problem = least_squares_problem()
    res = make(name).minimize(problem)
    assert isinstance(res, FitResult)
    assert res.method == name
    assert res.x.shape == (6,) and res.x.dtype == float
    assert isinstance(res.cost, float)
    assert res.cost == pytest.approx(evaluate(problem, res.x), rel=1e-9, abs=1e-18)  # the problem's fitness at x
    assert res.names == problem.names
    assert res.message == STATUS_MESSAGES.get(res.status, res.message) and res.message
    assert isinstance(res.success, bool) and res.success
    assert res.nit >= 1 and res.nfev >= 1
    assert res.wall_time_s > 0.0


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_same_seed_same_result(name):
    a = make(name).minimize(least_squares_problem(seed=4))
    b = make(name).minimize(least_squares_problem(seed=4))
    np.testing.assert_array_equal(a.x, b.x)
    assert a.cost == b.cost and a.nit == b.nit and a.nfev == b.nfev


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_built_from_its_config_file(name):
    cfg = yaml.safe_load((CONF / f"{name}.yaml").read_text())
    opt = make_optimizer(cfg)
    assert isinstance(opt, Optimizer) and opt.name == cfg["name"] == name
    assert set(opt.get_params()) >= {"max_iter"}


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_bad_input_is_refused_naming_it(name):
    with pytest.raises(ConfigError, match=r"^optimizer\.max_iter: must be an integer >= \d; got -1$"):
        make_optimizer({"name": name, "max_iter": -1})
    with pytest.raises(ConfigError, match="'problem' parameter"):
        make(name).minimize({"n": 6})  # type: ignore[arg-type]
