"""The calibration model: robot chain + tracker->base frame + one tool offset per target.

Full parameter vector ``x`` (layout in :class:`CalibrationModel.names`):

- kinematic parameter errors of the chain (``theta1``, ``d1``, ``a1``, ``alpha1`` ..., ``beta2``; mm / rad),
  zero = nominal;
- ``base_tx, base_ty, base_tz`` (mm) and ``base_rx, base_ry, base_rz`` (rad): ``tracker_T_base =
  T_ref · Trans(t) · Rot_x · Rot_y · Rot_z``, a correction of a reference frame ``T_ref`` (the closed-form
  registration), zero at the reference;
- ``tool_<T>_x/y/z`` (mm): the target's position in the flange frame, per target;
- with orientation data, ``tool_<T>_rx/ry/rz`` (rad): the target frame
  ``flange_R_target = R_ref_T · Rot_x Rot_y Rot_z``;
- with several tracker stations, ``station_<S>_tx/ty/tz/rx/ry/rz`` for every station after the first: its own
  ``tracker_T_base`` in the same form (its own reference frame). The first station's frame keeps the
  ``base_*`` names and is *the* ``tracker_T_base`` of the calibration.

Residuals are predicted minus measured: positions (mm) flattened row-major ``[x1, y1, z1, x2, ...]``,
then (when orientation is used) rotation vectors of ``R_pred R_meas^T`` (rad).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from robocal.kinematics.chain import RX, RY, RZ, TX, TY, TZ, Chain, build_chain, point_jacobians, propagate
from robocal.kinematics.transforms import matrix_to_rotvec, rotx, roty, rotz, so3_left_jacobian_inv
from robocal.robot import RobotDescription

BASE_NAMES = ("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz")

#: rows propagated at once for a Jacobian: the chain's recorded frames and the point Jacobians' temporaries are
#: ~10 arrays of (rows, 3, elements) floats, bounded at ~30 MB by taking the rows in chunks (each row's numbers
#: are its own: the result is the same to the bit)
CHUNK_ROWS = 4096


def _chunks(groups: list[np.ndarray]) -> Iterator[tuple[int, np.ndarray]]:
    """``(station, rows)`` of every station's rows in chunks of at most :data:`CHUNK_ROWS`."""
    for s, idx in enumerate(groups):
        for a in range(0, len(idx), CHUNK_ROWS):
            yield s, idx[a : a + CHUNK_ROWS]


def with_base(chain: Chain) -> Chain:
    """Prepend the six base-correction elements; their parameters follow the kinematic ones."""
    P = chain.n_params
    kinds = (TX, TY, TZ, RX, RY, RZ, *chain.kinds)
    return Chain(
        kinds=kinds,
        nominal=np.concatenate([np.zeros(6), chain.nominal]),
        joint=np.concatenate([-np.ones(6, dtype=int), chain.joint]),
        param=np.concatenate([np.arange(P, P + 6), chain.param]),
        fixed=(None,) * 6 + chain.fixed,
        param_names=chain.param_names + BASE_NAMES,
        n_joints=chain.n_joints,
    )


@dataclass(frozen=True)
class FitData:
    """Measurements prepared for fitting.

    q : (m, n) rad; p_mm : (m, 3) tracker frame; target_index : (m,) int;
    R_meas : (m, 3, 3) or None (target orientation in the tracker frame);
    station_index : (m,) int into the model's stations, or None (all rows from the first station).
    """

    q: np.ndarray
    p_mm: np.ndarray
    target_index: np.ndarray
    R_meas: np.ndarray | None = None
    station_index: np.ndarray | None = None

    @property
    def m(self) -> int:
        return self.q.shape[0]

    def with_q(self, q: np.ndarray) -> FitData:
        """The same measurements at other joint angles (e.g. corrected by a joint-level effect)."""
        return replace(self, q=q)

    def rows(self, idx: np.ndarray) -> FitData:
        """The measurements of rows ``idx``."""
        return FitData(
            q=self.q[idx],
            p_mm=self.p_mm[idx],
            target_index=self.target_index[idx],
            R_meas=None if self.R_meas is None else self.R_meas[idx],
            station_index=None if self.station_index is None else self.station_index[idx],
        )

    def station_rows(self, n_stations: int) -> list[np.ndarray]:
        """Row indices of each station (``n_stations`` lists; the first holds every row without station data)."""
        if n_stations <= 1 or self.station_index is None:
            return [np.arange(self.m)]
        return [np.flatnonzero(self.station_index == s) for s in range(n_stations)]


class CalibrationModel:
    """Predicts target positions (and orientations) from a full parameter vector; gives analytic Jacobians."""

    def __init__(
        self,
        robot: RobotDescription,
        target_names: tuple[str, ...] | list[str],
        orientation: bool = False,
        T_ref: np.ndarray | None = None,
        tool_R_ref: np.ndarray | None = None,
        stations: tuple[str, ...] | list[str] = (),
        station_T_ref: np.ndarray | None = None,
    ) -> None:
        self.robot = robot
        self.chain = build_chain(robot)
        self.full_chain = with_base(self.chain)
        self.target_names = tuple(target_names)
        self.orientation = bool(orientation)
        self.T_ref = np.eye(4) if T_ref is None else np.asarray(T_ref, dtype=float)
        self.station_names: tuple[str, ...] = tuple(stations) or ("S1",)
        S = len(self.station_names)
        if station_T_ref is None:
            station_T_ref = np.tile(self.T_ref, (S, 1, 1))
        self.station_T_ref = np.asarray(station_T_ref, dtype=float).reshape(S, 4, 4).copy()
        self.station_T_ref[0] = self.T_ref
        K = len(self.target_names)
        self.tool_R_ref = np.tile(np.eye(3), (K, 1, 1)) if tool_R_ref is None else np.asarray(tool_R_ref, float)
        names = list(self.full_chain.param_names)
        kinds = ["kinematic"] * self.chain.n_params + ["base"] * 6
        for t in self.target_names:
            names += [f"tool_{t}_x", f"tool_{t}_y", f"tool_{t}_z"]
            kinds += ["tool"] * 3
        if self.orientation:
            for t in self.target_names:
                names += [f"tool_{t}_rx", f"tool_{t}_ry", f"tool_{t}_rz"]
                kinds += ["tool_rot"] * 3
        self.n_local = len(names)  # the parameters of one station's view of the model
        for st in self.station_names[1:]:
            names += [f"station_{st}_{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")]
            kinds += ["base"] * 6
        self.names: tuple[str, ...] = tuple(names)
        self.kinds: tuple[str, ...] = tuple(kinds)
        pk = self.chain.param_kind
        units = ["mm" if k == "length" else "rad" for k in pk]
        units += ["mm"] * 3 + ["rad"] * 3 + ["mm"] * (3 * K) + (["rad"] * (3 * K) if self.orientation else [])
        units += (["mm"] * 3 + ["rad"] * 3) * (S - 1)
        self.units: tuple[str, ...] = tuple(units)
        self.n_chain = self.full_chain.n_params  # kinematic + base
        self.n = len(self.names)

    # ------------------------------------------------------------------ stations
    @property
    def n_stations(self) -> int:
        return len(self.station_names)

    def station_columns(self, s: int) -> np.ndarray:
        """Columns of the full parameter vector holding station ``s``'s six frame parameters."""
        if s == 0:
            P = self.chain.n_params
            return np.arange(P, P + 6)
        k0 = self.n_local + 6 * (s - 1)
        return np.arange(k0, k0 + 6)

    def local_columns(self, s: int) -> np.ndarray:
        """For station ``s``: the full-vector column of each parameter of its single-station view."""
        cols = np.arange(self.n_local)
        if s:
            P = self.chain.n_params
            cols[P : P + 6] = self.station_columns(s)
        return cols

    def _local(self, x: np.ndarray, s: int) -> np.ndarray:
        return x[..., self.local_columns(s)]

    # ------------------------------------------------------------------ layout helpers
    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown parameter {name!r}") from None

    def zeros(self) -> np.ndarray:
        return np.zeros(self.n)

    def tools(self, x: np.ndarray) -> np.ndarray:
        """Tool offsets ``(K, 3)`` (or ``(pop, K, 3)``) in the flange frame, mm."""
        K = len(self.target_names)
        return x[..., self.n_chain : self.n_chain + 3 * K].reshape(*x.shape[:-1], K, 3)

    def tool_rotations(self, x: np.ndarray) -> np.ndarray:
        """``flange_R_target`` per target, ``(K, 3, 3)``."""
        K = len(self.target_names)
        if not self.orientation:
            return self.tool_R_ref.copy()
        a = x[self.n_chain + 3 * K : self.n_chain + 6 * K].reshape(K, 3)

        return self.tool_R_ref @ rotx(a[:, 0]) @ roty(a[:, 1]) @ rotz(a[:, 2])

    def base_transform(self, x: np.ndarray, station: int = 0) -> np.ndarray:
        """``tracker_T_base`` (4, 4) of a station (the first by default) for the parameter vector ``x``."""
        xl = self._local(np.asarray(x, dtype=float), station)
        T_ref = self.station_T_ref[station]
        st = propagate(self.full_chain_base_only, np.zeros((1, self.chain.n_joints)), xl[: self.n_chain], T_ref)
        T = np.eye(4)
        T[:3, :3] = st.R.reshape(3, 3)
        T[:3, 3] = np.asarray(st.o).reshape(3)
        return T

    @property
    def full_chain_base_only(self) -> Chain:
        fc = self.full_chain
        return Chain(
            kinds=fc.kinds[:6],
            nominal=fc.nominal[:6],
            joint=fc.joint[:6],
            param=fc.param[:6],
            fixed=fc.fixed[:6],
            param_names=fc.param_names,
            n_joints=fc.n_joints,
        )

    # ------------------------------------------------------------------ prediction
    def predict(self, x: np.ndarray, q: np.ndarray, target_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted target positions ``(m, 3)`` and orientations ``(m, 3, 3)`` in the tracker frame.

        With ``x`` of shape ``(pop, n)`` the positions are ``(pop, m, 3)`` (orientation then omitted:
        an empty array is returned).
        """
        x = np.asarray(x, dtype=float)
        return self.predict_stations(x, FitData(q, np.zeros((len(q), 3)), np.asarray(target_index)))

    def predict_stations(self, x: np.ndarray, data: FitData) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` of the rows of ``data``, each in its own station's tracker frame."""
        groups = data.station_rows(self.n_stations)
        if len(groups) == 1:
            return self._predict1(x, data.q, data.target_index, self.T_ref)
        m = data.m
        p = np.zeros((*x.shape[:-1], m, 3))
        R = np.zeros((m, 3, 3))
        for s, idx in enumerate(groups):
            if len(idx):
                ps, Rs = self._predict1(self._local(x, s), data.q[idx], data.target_index[idx], self.station_T_ref[s])
                p[..., idx, :] = ps
                if x.ndim == 1:
                    R[idx] = Rs
        return p, (R if x.ndim == 1 else np.empty(0))

    def _predict1(
        self, x: np.ndarray, q: np.ndarray, target_index: np.ndarray, T_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        st = propagate(self.full_chain, q, x[..., : self.n_chain], T_ref)
        t = self.tools(x)[..., target_index, :]
        p = st.o + st.x * t[..., 0:1] + st.y * t[..., 1:2] + st.z * t[..., 2:3]
        if x.ndim == 2:
            return p, np.empty(0)
        R = st.R @ self.tool_rotations(x)[target_index]
        return p, R

    def residuals(self, x: np.ndarray, data: FitData) -> np.ndarray:
        """Residual vector (predicted - measured), shape ``(3m,)`` or ``(6m,)`` with orientation."""
        p, R = self.predict_stations(x, data)
        r = (p - data.p_mm).ravel()
        if self.orientation and data.R_meas is not None:
            rv = matrix_to_rotvec(R @ np.swapaxes(data.R_meas, -1, -2))
            r = np.concatenate([r, rv.ravel()])
        return r

    def batch_position_residuals(self, X: np.ndarray, data: FitData) -> np.ndarray:
        """Position residuals for a population ``X (pop, n)``: shape ``(pop, 3m)``."""
        p, _ = self.predict_stations(X, data)
        return (p - data.p_mm).reshape(X.shape[0], -1)

    def residuals_and_jacobian(self, x: np.ndarray, data: FitData) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (as :meth:`residuals`) and their analytic Jacobian ``(M, n)``."""
        x = np.asarray(x, dtype=float)
        groups = data.station_rows(self.n_stations)
        if len(groups) == 1 and data.m <= CHUNK_ROWS:
            return self._rj1(x, data, self.T_ref)
        m = data.m
        use_rot = self.orientation and data.R_meas is not None
        M = 3 * m * (2 if use_rot else 1)
        r = np.zeros(M)
        J = np.zeros((M, self.n))
        for s, idx in _chunks(groups):
            rs, Js = self._rj1(self._local(x, s), data.rows(idx), self.station_T_ref[s])
            ms = len(idx)
            pos = (3 * idx[:, None] + np.arange(3)).ravel()
            out_rows = np.concatenate([pos, 3 * m + pos]) if use_rot else pos
            r[out_rows] = rs
            J[np.ix_(out_rows, self.local_columns(s))] = Js[: 6 * ms if use_rot else 3 * ms]
        return r, J

    def _rj1(self, x: np.ndarray, data: FitData, T_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`residuals_and_jacobian` of one station's rows, on its single-station parameter vector."""
        m = data.m
        K = len(self.target_names)
        st = propagate(self.full_chain, data.q, x[: self.n_chain], T_ref, record=True)
        t = self.tools(x)[data.target_index]
        p = st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]
        J_eta, W_eta, _, _ = point_jacobians(self.full_chain, st, p)
        use_rot = self.orientation and data.R_meas is not None
        M = 3 * m * (2 if use_rot else 1)
        J = np.zeros((M, self.n_local))
        Jp = J[: 3 * m].reshape(m, 3, self.n_local)
        Jp[:, :, : self.n_chain] = J_eta
        Rf = np.stack([st.x, st.y, st.z], axis=-1)  # (m, 3, 3)
        rows = np.arange(m)
        for c in range(3):
            Jp[rows, :, self.n_chain + 3 * data.target_index + c] = Rf[:, :, c]
        r = (p - data.p_mm).ravel()
        if use_rot:
            assert data.R_meas is not None
            Rt = self.tool_rotations(x)
            R = Rf @ Rt[data.target_index]
            rv = matrix_to_rotvec(R @ np.swapaxes(data.R_meas, -1, -2))
            r = np.concatenate([r, rv.ravel()])
            Jw = J[3 * m :].reshape(m, 3, self.n_local)
            Jw[:, :, : self.n_chain] = W_eta
            # tool rotation Rot_x(a) Rot_y(b) Rot_z(c) after R_ref: world axes
            a = x[self.n_chain + 3 * K : self.n_chain + 6 * K].reshape(K, 3)[data.target_index]
            A = Rf @ self.tool_R_ref[data.target_index]
            ux = A[:, :, 0]
            B = A @ rotx(a[:, 0])
            uy = B[:, :, 1]
            uz = (B @ roty(a[:, 1]))[:, :, 2]
            base_col = self.n_chain + 3 * K + 3 * data.target_index
            Jw[rows, :, base_col] = ux
            Jw[rows, :, base_col + 1] = uy
            Jw[rows, :, base_col + 2] = uz
            # exact derivative of log(R_pred R_meas^T) for a left perturbation of R_pred
            Jw[:] = so3_left_jacobian_inv(rv) @ Jw
        return r, J

    def joint_jacobians(self, x: np.ndarray, data: FitData) -> tuple[np.ndarray, np.ndarray | None]:
        """Jacobians of the residuals w.r.t. the joint angles: positions ``(m, 3, n)`` mm/rad and, when the model
        uses orientations, the rotation residuals ``(m, 3, n)`` (with the same left-Jacobian correction as
        :meth:`residuals_and_jacobian`), else None."""
        q = data.q
        m, n = q.shape
        use_rot = self.orientation and data.R_meas is not None
        J_q = np.zeros((m, 3, n))
        W_q = np.zeros((m, 3, n)) if use_rot else None
        for s, idx in _chunks(data.station_rows(self.n_stations)):
            xl = self._local(np.asarray(x, dtype=float), s)
            st = propagate(self.full_chain, q[idx], xl[: self.n_chain], self.station_T_ref[s], record=True)
            t = self.tools(xl)[data.target_index[idx]]
            p = st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]
            _, _, Jq, Wq = point_jacobians(self.full_chain, st, p)
            J_q[idx] = Jq
            if W_q is not None:
                assert data.R_meas is not None
                Rf = np.stack([st.x, st.y, st.z], axis=-1)
                R = Rf @ self.tool_rotations(xl)[data.target_index[idx]]
                rv = matrix_to_rotvec(R @ np.swapaxes(data.R_meas[idx], -1, -2))
                W_q[idx] = so3_left_jacobian_inv(rv) @ Wq
        return J_q, W_q

    def joint_jacobian(
        self, x: np.ndarray, q: np.ndarray, target_index: np.ndarray, station_index: np.ndarray | None = None
    ) -> np.ndarray:
        """Jacobian of target positions w.r.t. the joint angles, ``(m, 3, n)`` mm/rad (each row's tracker frame)."""
        groups = FitData(q, q[:, :3], target_index, station_index=station_index).station_rows(self.n_stations)
        J_q = np.zeros((len(q), 3, q.shape[1]))
        for s, idx in _chunks(groups):
            xl = self._local(np.asarray(x, dtype=float), s)
            st = propagate(self.full_chain, q[idx], xl[: self.n_chain], self.station_T_ref[s], record=True)
            t = self.tools(xl)[target_index[idx]]
            p = st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]
            J_q[idx] = point_jacobians(self.full_chain, st, p)[2]
        return J_q
