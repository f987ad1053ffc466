"""Cross-validation's groups: a configuration measured again under another pose id is one group (issue 33).

IPA's UR10 series B measures 293 of its 1 495 rows at a configuration it measured before, each under a pose id of
its own; grouped by pose id, a fold was judged on configurations another fold was fitted on, and the
cross-validated error under-read the held-out one (B 0.099 vs 0.109, D 0.099 vs 0.112)."""

from __future__ import annotations

import numpy as np

from robocal.discovery.cv import pose_groups
from robocal.identification.thin import SAME_CONFIGURATION_DEG


def test_a_configuration_measured_again_under_another_pose_id_is_one_group():
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, size=(6, 6))
    q[4] = q[1] + np.deg2rad(0.5 * SAME_CONFIGURATION_DEG)  # pose P4 repeats P1 (encoder scatter)
    q[5] = q[2] + np.deg2rad([2 * SAME_CONFIGURATION_DEG, 0, 0, 0, 0, 0])  # P5 is another configuration
    pid = np.array(["P0", "P1", "P2", "P3", "P4", "P5"])
    g = pose_groups(pid, q)
    assert g.tolist() == ["P0", "P1", "P2", "P3", "P1", "P5"]


def test_several_targets_of_one_pose_and_a_chain_of_repeats_stay_together():
    q = np.zeros((5, 6))
    q[2:] = 1.0
    q[3, 0] += np.deg2rad(0.8 * SAME_CONFIGURATION_DEG)
    q[4, 0] += np.deg2rad(1.6 * SAME_CONFIGURATION_DEG)  # within the tolerance of row 3, not of row 2
    pid = np.array(["A", "A", "B", "C", "D"])  # A: two targets of one pose
    assert pose_groups(pid, q).tolist() == ["A", "A", "B", "B", "B"]


def test_a_campaign_without_repeats_keeps_its_pose_ids():
    q = np.arange(30, dtype=float).reshape(5, 6)
    pid = np.array(["x", "y", "z", "y", "w"])  # y: two rows (targets) at one pose
    q[3] = q[1]
    assert pose_groups(pid, q).tolist() == pid.tolist()


def test_the_folds_do_not_depend_on_how_the_pose_ids_are_written():
    """A campaign whose pose ids are integers (0, 1, ..., 139) falls in the folds its zero-padded ids (p0000, ...)
    fall in: np.unique sorted them as text ("10" before "2"), and on a near tie another effect was named (a
    newcomer's column campaign: four effects at 0.816 mm, or two at 0.438, by the ids' spelling alone)."""
    from robocal.discovery.cv import group_labels

    n = 140
    padded = np.array([f"p{i:04d}" for i in range(n)])
    plain = np.array([str(i) for i in range(n)])
    for ids in (padded, plain):
        uniq, inv, counts = group_labels(np.repeat(ids, 3))
        assert uniq.tolist() == ids.tolist() and (counts == 3).all() and np.array_equal(inv, np.repeat(np.arange(n), 3))
    # ids of one padded width keep np.unique's order (the folds of every campaign so written are unchanged)
    mixed = np.array(["B00856", "A00002", "B00010", "c00", "c01"])
    assert group_labels(mixed)[0].tolist() == np.unique(mixed).tolist()
