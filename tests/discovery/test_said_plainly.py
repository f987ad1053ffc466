"""What discovery says where its figures cannot speak for themselves (newcomer pass 7): the noise a held-out error
implies when "unexplained" rests on the configured noise alone (a laser tracker of 0.02 mm was told "unexplained"
at a held-out error on its own floor, and told to set noise_mm after setting it); transmission orders the poses
cannot resolve; a transmission error peaking at its highest fitted order."""

from __future__ import annotations

from robocal.commands.discover import _noise_words
from robocal.identification.noise import MEAN_NORM_3D, noise_hint

CONFIGURED = "the configured value: the campaign has no model-free noise estimate (one target, no repeated poses)"


def _summ(cv_mean: float, because: str = CONFIGURED) -> dict:
    return {"noise": {"used_mm": 0.015, "used_because": because},
            "cross_validation": {"cv_mean_position_mm": cv_mean}, "uses_orientation": False}  # fmt: skip


def test_a_held_out_error_above_the_configured_floor_names_the_noise_it_implies():
    h = noise_hint(_summ(0.0322))
    assert f"{0.0322 / MEAN_NORM_3D:.4f} mm" in h and "set noise_mm=0.020" in h  # 0.0322 / 1.596 = 0.0202
    # at the configured floor (within 10 %), or with a model-free estimate of the noise: nothing to say
    assert noise_hint(_summ(0.015 * MEAN_NORM_3D * 1.05)) == ""
    larger = "the larger of the configured 0.015 mm and the model-free estimate 0.02 mm (repeated poses)"
    assert noise_hint(_summ(0.0322, larger)) == ""


def test_the_console_does_not_ask_for_a_noise_already_given():
    g = {"noise_used_mm": 0.02, "noise_used_because": CONFIGURED}
    assert "set noise_mm" not in _noise_words(g, set_here=True) and "noise_mm given" in _noise_words(g, True)
    assert "set noise_mm" in _noise_words(g)


def test_transmission_orders_the_poses_cannot_resolve_are_said():
    """``transmission_orders=[48, 60]`` on 300 poses: the effect vanished from the search without a word."""
    from robocal.discovery.config import DiscoveryConfig
    from robocal.discovery.grow import orders_not_tried, resolved_orders

    cfg = DiscoveryConfig.from_mapping({"transmission_orders": [48, 60]})
    assert resolved_orders(cfg, 300) == []
    s = orders_not_tried(cfg, 300)
    assert s is not None and "48, 60 not tried" in s.reason and "not tried at all" not in s.reason
    assert "the transmission error is not tried" in s.reason and "has 300" in s.reason
    cfg2 = DiscoveryConfig.from_mapping({"transmission_orders": [12, 48]})
    assert "only order 12 is tried" in orders_not_tried(cfg2, 300).reason
    assert orders_not_tried(cfg2, 400) is None  # 8 x 48 = 384 poses resolve both
    assert orders_not_tried(DiscoveryConfig.from_mapping({"effects": ["gear"]}), 10) is None


def test_a_transmission_error_peaking_at_its_highest_fitted_order_carries_a_caveat():
    """37 cycles per revolution planted, orders up to 36 fitted: read as harmonic 36 at 2.7x the amplitude."""
    from robocal.discovery.summary import edge_order

    def est(amps: dict[int, float], order: int) -> dict:
        out = {f"harmonic_{h}_amplitude_deg": {"value": a, "stderr": 0.001, "unit": "deg"} for h, a in amps.items()}
        return {**out, "order": {"value": order, "stderr": None, "unit": "harmonics per revolution"}}

    assert "highest order fitted (36)" in edge_order(est({36: 0.011, 10: 0.0075, 35: 0.004}, 36))
    assert edge_order(est({17: 0.006, 36: 0.002}, 36)) == ""  # resolved inside the fitted orders


def test_a_strong_effects_p_value_is_a_number_not_null():
    """scipy's F logsf underflows to -inf near F ~ 300 (10 and 2 000 degrees of freedom): discovery.json wrote null
    and the report crashed formatting it (newcomer pass 8: a proposed equation at F = 3 594, nothing written)."""
    import numpy as np
    from scipy import stats

    from robocal.discovery.ftest import f_log10_sf

    for F, d1, d2 in [(20.0, 3, 300), (100.0, 10, 2000), (50.0, 2, 5000)]:  # where logsf is finite: the same
        assert f_log10_sf(F, d1, d2) == stats.f.logsf(F, d1, d2) / np.log(10.0)
    assert not np.isfinite(stats.f.logsf(3594.0, 2, 2000))  # the premise
    deep = [f_log10_sf(F, 2, 2000) for F in (1000.0, 3594.0, 1e5)]
    assert all(np.isfinite(deep)) and deep[0] > deep[1] > deep[2]  # finite and falling with F
    # continuous where scipy gives out: the identity's value just below the underflow matches scipy's
    F0 = 150.0
    assert np.isfinite(stats.f.logsf(F0, 10, 2000))
    from scipy import special

    a, b, x = 1000.0, 5.0, 2000.0 / (2000.0 + 10 * F0)
    ln = a * np.log(x) + b * np.log1p(-x) - np.log(a) - special.betaln(a, b)
    ln += np.log(special.hyp2f1(a + b, 1, a + 1, x))
    assert abs(ln - stats.f.logsf(F0, 10, 2000)) < 1e-9 * abs(ln)
