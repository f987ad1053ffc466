"""ThermalModel persistence / evaluation and the per-parameter regression on synthetic drift with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.thermal.model import ParameterModel, ThermalModel, design, monomials
from robocal.thermal.regression import RegressionConfig, fit_parameter


def _model() -> ThermalModel:
    p1 = ParameterModel(
        "d1",
        "length",
        "expansion",
        ("T_a_C",),
        ((1,),),
        np.array([0.01]),
        np.array([1e-3]),
        np.eye(1) * 1e-6,
        nominal=675.0,
    )
    p2 = ParameterModel(
        "theta4",
        "angle",
        "polynomial",
        ("T_a_C", "T_b_C"),
        tuple(monomials(2, 2)),
        np.array([1e-5, -2e-5, 1e-7, 0.0, 3e-7]),
        np.full(5, 1e-7),
        np.eye(5) * 1e-14,
    )
    return ThermalModel(
        "r",
        ("d1", "a1", "theta4"),
        ("T_a_C", "T_b_C"),
        np.array([20.0, 21.0]),
        np.array([[20.0, 30.0], [21.0, 29.0]]),
        (p1, p2),
    )


def test_monomials_count_and_order() -> None:
    # C(s + p, p) - 1 monomials of order 1..p (eq. 7 without the constant)
    assert len(monomials(3, 2)) == 9
    assert monomials(2, 2) == [(1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
    X = design(np.array([[2.0, 3.0]]), monomials(2, 2))
    assert np.allclose(X, [[2, 3, 4, 6, 9]])


def test_deta_chain_order_and_round_trip(tmp_path) -> None:
    m = _model()
    T = np.array([[25.0, 23.0], [20.0, 21.0]])
    d = m.deta(T)
    assert d.shape == (2, 3)
    x1, x2 = 5.0, 2.0
    assert d[0, 0] == pytest.approx(0.01 * x1)
    assert d[0, 1] == 0.0  # a1 has no model
    assert d[0, 2] == pytest.approx(1e-5 * x1 - 2e-5 * x2 + 1e-7 * x1**2 + 3e-7 * x2**2)
    assert np.all(d[1] == 0.0)  # at the reference temperatures there is no drift
    p = tmp_path / "m.json"
    from robocal.io import write_json

    write_json(p, m.to_dict())
    m2 = ThermalModel.from_json(p)
    assert np.array_equal(m2.deta(T), d)
    assert m2.parameter("d1").lambda_per_C == pytest.approx(0.01 / 675.0)
    assert m.out_of_range(np.array([[31.0, 25.0]])).tolist() == [[True, False]]
    with pytest.raises(ValueError, match=r"shape \(m, 2\)"):
        m.deta(np.zeros((2, 3)))
    assert "Δd1 = 0.01 × (T_a_C − 20.00)" in m.equations()[0]  # the sensor by its one name (issue 23, item 12)


def test_equations_in_the_papers_absolute_form_and_with_uncertainties() -> None:
    """eq. 28 as the paper prints it (polynomials in absolute temperatures) is the same function as the model, and
    the standard errors carried through the change of variables match a Monte Carlo of the coefficients."""
    m = _model()
    p = m.parameter("theta4")
    ref = dict(zip(m.sensors, m.T_ref_C.tolist(), strict=True))
    terms, coef, se = p.absolute(ref)
    assert terms[0] == (0, 0) and len(terms) == 6  # constant + the 5 monomials of order <= 2 in 2 sensors
    rng = np.random.default_rng(3)
    T = rng.uniform(15.0, 40.0, size=(50, 2))
    assert np.allclose(design(T, terms[1:]) @ coef[1:] + coef[0], p.evaluate(T - m.T_ref_C), rtol=1e-9, atol=1e-15)
    # a correlated covariance, so that the propagation is not just the diagonal
    A = rng.normal(size=(5, 5)) * 1e-7
    q = ParameterModel(p.name, p.kind, p.form, p.sensors, p.terms, p.coefficients, np.sqrt(np.diag(A @ A.T)), A @ A.T)
    _, c_abs, se_abs = q.absolute(ref)
    assert np.allclose(c_abs, coef)  # same coefficients, only the covariance differs
    draws = rng.multivariate_normal(q.coefficients, q.covariance, size=2000)
    mc = np.array(
        [ParameterModel(p.name, p.kind, p.form, p.sensors, p.terms, d, se, np.eye(5)).absolute(ref)[1] for d in draws]
    )
    # 2000 draws: the sample std is within ~3.2 % (1 sigma) of the truth; 12 % is ~4 sigma
    assert np.allclose(mc.std(axis=0), se_abs, rtol=0.12)
    eq_abs, eq_se = m.equations(absolute=True), m.equations(stderr=True)
    assert eq_abs[0] == m.equations()[0]  # expansions are printed c × (t − T_ref), as in the paper
    assert eq_abs[1].startswith("Δtheta4 = 0.0003923 ") and "T_a_C^2" in eq_abs[1] and "Δ" not in eq_abs[1][9:]
    assert "(0.01 ± 0.001) × (T_a_C − 20.00)" in eq_se[0] and eq_se[1].count("±") == 5
    # the reports print angles in degrees, as their tables do; lengths unchanged (issue 23, item 12)
    deg = m.equations(absolute=True, deg=True)
    assert deg[0] == eq_abs[0] and deg[1].startswith(f"Δtheta4 = {0.0003923 * 180 / np.pi:.4g} ")


def _warm_up(n: int = 6) -> np.ndarray:
    """Sensor differences of a first-order warm-up at 30..180 min: (n, 3)."""
    t = np.arange(1, n + 1) * 30.0
    rise, tau = np.array([10.0, 7.0, 9.0]), np.array([35.0, 60.0, 45.0])
    return rise * (1 - np.exp(-t[:, None] / tau))


def _noise(rng: np.random.Generator, n: int, v: float) -> np.ndarray:
    # the structure of identified drift: a shared reference error plus one error per state, each of variance v
    return rng.normal(0, np.sqrt(v)) + rng.normal(0, np.sqrt(v), n)


def test_expansion_coefficient_coverage() -> None:
    """The stated standard error covers the truth as often as it should (Monte Carlo, known sensor)."""
    x = _warm_up()
    sensors = ("T_a_C", "T_b_C", "T_c_C")
    c_true, v = 0.012, 0.004**2
    rng = np.random.default_rng(3)
    z = []
    for _ in range(300):
        y = c_true * x[:, 1] + _noise(rng, len(x), v)
        out = fit_parameter("d1", "length", x, y, v, sensors, ["T_b_C"], RegressionConfig(allow_none=False))
        assert out.model is not None
        z.append((out.model.coefficients[0] - c_true) / out.model.stderr[0])
    z = np.abs(np.array(z))
    # nominal 95 % at |z| < 1.96; the error is scaled up by max(1, reduced chi2) so the coverage is >= nominal;
    # 300 draws give a binomial spread of ~1.3 %: accept 0.92..0.995
    assert 0.92 <= np.mean(z < 1.96) <= 0.995


def test_polynomial_selection_and_recovery() -> None:
    """CV picks the true sensors and order when the signal is clear; coefficients within 3 std. errors."""
    x = _warm_up()
    sensors = ("T_a_C", "T_b_C", "T_c_C")
    # theta = a * x_a + b * x_a^2 (rad), with small state noise
    a, b, v = 6e-5, 3e-6, (2e-6) ** 2
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(20):
        y = a * x[:, 0] + b * x[:, 0] ** 2 + _noise(rng, len(x), v)
        out = fit_parameter(
            "theta6", "angle", x, y, v, sensors, list(sensors), RegressionConfig(), forms=("polynomial",)
        )
        m = out.model
        assert m is not None
        if m.sensors == ("T_a_C",) and m.terms == ((1,), (2,)):
            hits += 1
            z = (m.coefficients - [a, b]) / m.stderr
            assert np.all(np.abs(z) < 3.5)  # 3.5 sigma: two coefficients, 20 draws, no false alarm expected
    assert hits >= 15  # the other sensors' curves differ in time constant: the right model should usually win


def test_no_drift_for_pure_noise() -> None:
    """A parameter that does not move gets no model (the chi2 test at alpha = 1e-3) in almost every draw."""
    x = _warm_up()
    sensors = ("T_a_C", "T_b_C", "T_c_C")
    rng = np.random.default_rng(1)
    v = 1e-6
    fitted = sum(
        fit_parameter(
            "alpha1",
            "angle",
            x,
            _noise(rng, 6, v),
            v,
            sensors,
            list(sensors),
            RegressionConfig(),
            forms=("polynomial",),
        ).model
        is not None
        for _ in range(100)
    )
    # alpha = 1e-3 per test, but the best of ~20 candidate models is tested: allow a few false models in 100
    assert fitted <= 5


def test_cross_validation_table_states_its_unit() -> None:
    """The report's cross-validation table gives the CV errors a unit: mm for a length, degrees for an angle, as
    every other table of the report (issue 30, item 11: "CV rmse" had none and mixed mm with rad)."""
    from types import SimpleNamespace

    from robocal.thermal.report import cv_rows, model_cv_row

    x = _warm_up()
    sensors = ("T_a_C", "T_b_C", "T_c_C")
    rng = np.random.default_rng(0)
    v = (2e-6) ** 2
    y = 6e-5 * x[:, 0] + _noise(rng, len(x), v)
    ang = fit_parameter("theta6", "angle", x, y, v, sensors, list(sensors), RegressionConfig(), forms=("polynomial",))
    assert ang.model is not None
    row = model_cv_row(ang.model)
    deg = 180.0 / np.pi
    assert row["unit"] == "deg"
    assert row["CV rmse"] == pytest.approx(ang.model.stats["cv_rmse"] * deg, rel=1e-12)
    assert row["'no drift' CV rmse"] == pytest.approx(ang.model.stats["no_drift_cv_rmse"] * deg, rel=1e-12)
    assert row["next best"].endswith(" deg)")
    # a parameter without a significant drift (pure noise) gets its row in its own unit too
    flat = fit_parameter("d1", "length", x, _noise(rng, len(x), 1e-6), 1e-6, sensors, list(sensors), RegressionConfig())
    assert flat.model is None
    chain = SimpleNamespace(param_names=("d1", "theta6"), param_kind=("length", "angle"))
    fit = SimpleNamespace(
        outcomes={"d1": flat, "theta6": ang}, reference=SimpleNamespace(model=SimpleNamespace(chain=chain))
    )
    rows = {r["parameter"]: r for r in cv_rows(fit)}
    assert rows["d1"]["unit"] == "mm" and rows["theta6"]["unit"] == "deg"
    null = next(r for r in flat.table if r["model"] == "none")
    assert rows["d1"]["CV rmse"] == pytest.approx(null["cv_rmse"], rel=1e-12)
    assert rows["d1"]["next best"].endswith(" mm)")
