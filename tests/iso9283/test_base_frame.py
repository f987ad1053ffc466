"""The tracker registered to the robot base by axis circles (robocal.iso9283.base_frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from robocal.errors import DataError
from robocal.iso9283.base_frame import fit_circle, register_by_circles
from robocal.kinematics.chain import build_chain, propagate
from robocal.kinematics.transforms import homogeneous, matrix_from_rpy
from robocal.robot import load_robot


def test_fit_circle_finds_centre_radius_and_the_turning_sense() -> None:
    centre, r = np.array([100.0, -50.0, 300.0]), 800.0
    e1, e2 = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])  # normal +x
    ang = np.deg2rad(np.arange(-30.0, 31.0, 5.0))
    p = centre + r * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)
    c = fit_circle(p, ang)
    np.testing.assert_allclose(c.centre, centre, atol=1e-6)
    np.testing.assert_allclose(c.normal, [1.0, 0.0, 0.0], atol=1e-12)
    assert c.radius_mm == pytest.approx(r) and c.rms_mm < 1e-6 and c.span_deg == pytest.approx(60.0)
    assert fit_circle(p, -ang).normal[0] == pytest.approx(-1.0)  # the joint turning the other way: -x


def _write(path: Path, q_deg: np.ndarray, axis: list[int], p: np.ndarray) -> Path:
    head = "axis," + ",".join(f"q{j + 1}_deg" for j in range(q_deg.shape[1])) + ",x_mm,y_mm,z_mm"
    rows = [",".join([str(a), *map(str, q), *map(str, x)]) for a, q, x in zip(axis, q_deg, p, strict=True)]
    path.write_text("\n".join([head, *rows]) + "\n")
    return path


def _circles(T: np.ndarray, eta: np.ndarray | None = None) -> tuple[np.ndarray, list[int], np.ndarray]:
    robot = load_robot("kr16_2")
    chain = build_chain(robot)
    q0 = np.array([5.0, -70.0, 75.0, 10.0, 45.0, 20.0])
    q = np.vstack([np.tile(q0, (19, 1)), np.tile(q0, (13, 1))])
    q[:19, 0] += np.arange(-45.0, 46.0, 5.0)
    q[19:, 1] += np.arange(-30.0, 31.0, 5.0)
    s = propagate(chain, np.deg2rad(q), np.zeros(chain.n_params) if eta is None else eta)
    p = s.o + s.z * 120.0
    return q, [1] * 19 + [2] * 13, p @ T[:3, :3].T + T[:3, 3]


def test_the_nominal_robot_gives_back_its_tracker_frame(tmp_path: Path) -> None:
    T = homogeneous(matrix_from_rpy(np.deg2rad([0.3, -0.5, 135.0])), np.array([2500.0, 1200.0, -350.0]))
    q, axis, p = _circles(T)
    reg = register_by_circles(_write(tmp_path / "base_circles.csv", q, axis, p), load_robot("kr16_2"))
    np.testing.assert_allclose(reg.tracker_T_base, T, atol=1e-6)
    assert reg.info()["axis1"]["points"] == 19 and reg.info()["axis2"]["span_deg"] == pytest.approx(60.0)


def test_joint_1_errors_are_part_of_the_base(tmp_path: Path) -> None:
    """A robot whose axis 1 is offset, tilted and turned (a1, alpha1, theta1) and whose axis 2 sits higher (d1):
    the circles find the base those axes define, i.e. the tracker frame moved by exactly those four errors."""
    chain = build_chain(load_robot("kr16_2"))
    eta = np.zeros(chain.n_params)
    err = {"alpha1": 2e-4, "a1": 0.4, "theta1": -3e-4, "d1": -0.5}
    for k, v in err.items():
        eta[chain.param_names.index(k)] = v
    T = np.eye(4)
    q, axis, p = _circles(T, eta)
    reg = register_by_circles(_write(tmp_path / "base_circles.csv", q, axis, p), load_robot("kr16_2"))
    # MD-H link 1: Rot_x(alpha1) Trans_x(a1) Rot_z(theta1) Trans_z(d1) in front of the nominal link 1
    from robocal.kinematics.transforms import rotx, rotz

    D = homogeneous(rotx(err["alpha1"]), np.zeros(3)) @ homogeneous(np.eye(3), np.array([err["a1"], 0.0, 0.0]))
    D = D @ homogeneous(rotz(err["theta1"]), np.zeros(3)) @ homogeneous(np.eye(3), np.array([0.0, 0.0, err["d1"]]))
    np.testing.assert_allclose(reg.tracker_T_base, D, atol=1e-6)


@pytest.mark.parametrize(
    ("edit", "message", "row", "column"),
    [
        (lambda q, a, p: (q, [3, *a[1:]], p), "axis must be 1 or 2", 2, "axis"),
        (
            lambda q, a, p: (np.vstack([q[:2], q[2:3] + np.array([0, 1, 0, 0, 0, 0]), q[3:]]), a, p),
            "only joint 1",
            4,
            "q2_deg",
        ),
        (lambda q, a, p: (q[:23], a[:23], p[:23]), "at least 5", None, "axis"),
    ],
)
def test_bad_circle_files_name_file_row_and_column(tmp_path: Path, edit, message, row, column) -> None:  # type: ignore[no-untyped-def]
    q, axis, p = edit(*_circles(np.eye(4)))
    path = _write(tmp_path / "base_circles.csv", q, axis, p)
    with pytest.raises(DataError, match=message) as e:
        register_by_circles(path, load_robot("kr16_2"))
    assert e.value.file == str(path) and e.value.column == column and e.value.row == row
