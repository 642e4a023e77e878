"""Truth models: rigid-body attitude plant and prescribed (kinematic) attitude motion.

Both are small Diagrams around a ``SymbolicVectorSystem``: the right-hand side is a
symbolic expression evaluated in C++, so Drake's integrators run them at C++ speed
(a Python ``LeafSystem`` derivative costs tens of microseconds per evaluation).

Quaternion norm: the kinematics carry the standard stabilization term
``q_dot = 1/2 q ⊗ [0, w] + k (1 - q'q) q``.  It acts only along ``q`` (a scaling,
which does not change the rotation) and drives ``|q|`` to 1, so the norm cannot drift (the
output is the state itself; tests bound ``| |q| - 1 |``).

Note: ``Diagram.SetRandomContext`` resets state and parameters to their defaults; set the
initial state and inertia *after* it (the scenario builder does).
"""

from __future__ import annotations

import numpy as np
from pydrake.symbolic import Expression, Variable, if_then_else
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, SymbolicVectorSystem

NORM_STABILIZATION_GAIN = 1.0  # 1/s


def _quat_kinematics(q, w, gain=NORM_STABILIZATION_GAIN):
    """``1/2 q ⊗ [0, w] + gain (1 - q'q) q`` for symbolic q (4) and w (3)."""
    qw, qx, qy, qz = q
    wx, wy, wz = w
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    k = gain * (1.0 - n2)
    return [
        0.5 * (-qx * wx - qy * wy - qz * wz) + k * qw,
        0.5 * (qw * wx + qy * wz - qz * wy) + k * qx,
        0.5 * (qw * wy - qx * wz + qz * wx) + k * qy,
        0.5 * (qw * wz + qx * wy - qy * wx) + k * qz,
    ]


def validate_inertia(inertia, field: str = "inertia") -> np.ndarray:
    """Return the 3x3 inertia as an array, or raise naming ``field`` and the value."""
    I = np.asarray(inertia, dtype=float)
    if I.shape == (3,):
        I = np.diag(I)
    if I.shape != (3, 3) or not np.all(np.isfinite(I)):
        raise ValueError(f"{field}: got {inertia!r}; must be 3 finite principal moments or a 3x3 matrix (kg m^2)")
    if not np.allclose(I, I.T, rtol=0, atol=1e-12 * max(1.0, np.abs(I).max())):
        raise ValueError(f"{field}: got {I.tolist()}; must be symmetric")
    eig = np.linalg.eigvalsh(I)
    if eig[0] <= 0:
        raise ValueError(f"{field}: got {I.tolist()} with eigenvalues {eig.tolist()}; must be positive definite")
    # Triangle inequality of principal moments (a physical rigid body).
    if eig[0] + eig[1] < eig[2] * (1 - 1e-12):
        raise ValueError(
            f"{field}: principal moments {eig.tolist()} violate the triangle inequality "
            "I1 + I2 >= I3; not a physical rigid body"
        )
    return I


# RigidBodyAttitudePlant's default inertia (kg m^2): one array, created once, as the default was.
_UNIT_INERTIA = np.diag([1.0, 1.0, 1.0])


class RigidBodyAttitudePlant(Diagram):
    """Rigid-body rotational dynamics and quaternion kinematics.

    ``I w_dot + w x (I w) = torque_B``;  ``q_IB_dot = 1/2 q_IB ⊗ [0, w_IB_B]``;
    ``d/dt w_IB_B_integral = w_IB_B`` (lets an averaging gyro deliver the exact mean
    rate over its interval).

    Two forms of Euler's equations, chosen by the constructor's inertia (the cost of a
    ``SymbolicVectorSystem`` evaluation grows with its variables and products: every
    variable is a look-up, every factor a ``pow``):

    * **principal axes** (a diagonal inertia): ``w_dot_i = tau_i / I_i + c_i w_j w_k``
      with ``c_0 = (I_1 - I_2) / I_0`` and cyclic, ~2.5x cheaper per evaluation than the
      general form. :meth:`SetInertia` then accepts diagonal inertias only (any principal
      moments per context);
    * **general** (a full inertia): ``w_dot = I^-1 (tau - w x I w)``, any inertia per context.

    Input ports:
        torque_B (3): external torque on the body, body frame (N m).
    Output ports:
        q_IB (4): attitude, wxyz, unit norm.
        w_IB_B (3): angular velocity of B in I, body frame (rad/s).
        w_IB_B_integral (3): integral of ``w_IB_B`` since t = 0 (rad).
    Continuous state (of the inner ``SymbolicVectorSystem``, 10):
        ``[q_IB (4), w_IB_B (3), w_IB_B_integral (3)]``.
    Numeric parameter: principal axes (9): ``[I_i (3), 1 / I_i (3), c_i (3)]``; general (18):
    the inertia (row-major 3x3, kg m^2) and its inverse. Set them with :meth:`SetInertia`,
    never by hand.
    """

    def __init__(self, inertia=_UNIT_INERTIA):
        Diagram.__init__(self)
        self._default_inertia = validate_inertia(inertia)
        I0 = self._default_inertia
        self.principal_axes = bool(np.all(I0 == np.diag(np.diag(I0))))
        q = [Variable(f"q{i}") for i in range(4)]
        w = [Variable(f"w{i}") for i in range(3)]
        th = [Variable(f"theta{i}") for i in range(3)]
        tau = [Variable(f"tau{i}") for i in range(3)]
        if self.principal_axes:
            p_I = [Variable(f"I{i}") for i in range(3)]
            p_inv = [Variable(f"Iinv{i}") for i in range(3)]
            p_c = [Variable(f"c{i}") for i in range(3)]
            parameters = p_I + p_inv + p_c
            w_dot = [p_inv[i] * tau[i] + p_c[i] * w[(i + 1) % 3] * w[(i + 2) % 3] for i in range(3)]
        else:
            p_I = [Variable(f"I{i}") for i in range(9)]
            p_Iinv = [Variable(f"Iinv{i}") for i in range(9)]
            parameters = p_I + p_Iinv
            # Written out element by element (numpy dot on object arrays warns spuriously).
            Iw = [sum(p_I[3 * r + c] * w[c] for c in range(3)) for r in range(3)]
            gyro = [w[1] * Iw[2] - w[2] * Iw[1], w[2] * Iw[0] - w[0] * Iw[2], w[0] * Iw[1] - w[1] * Iw[0]]
            rhs = [tau[r] - gyro[r] for r in range(3)]
            w_dot = [sum(p_Iinv[3 * r + c] * rhs[c] for c in range(3)) for r in range(3)]
        dynamics = _quat_kinematics(q, w) + list(w_dot) + list(w)
        output = list(q) + list(w) + list(th)
        self._symbolic = SymbolicVectorSystem(
            state=q + w + th, input=tau, parameter=parameters, dynamics=dynamics, output=output
        )
        builder = DiagramBuilder()
        sym = builder.AddNamedSystem("rigid_body_dynamics", self._symbolic)
        demux = builder.AddNamedSystem("demux", Demultiplexer([4, 3, 3]))
        builder.Connect(sym.get_output_port(), demux.get_input_port())
        builder.ExportInput(sym.get_input_port(), "torque_B")
        builder.ExportOutput(demux.get_output_port(0), "q_IB")
        builder.ExportOutput(demux.get_output_port(1), "w_IB_B")
        builder.ExportOutput(demux.get_output_port(2), "w_IB_B_integral")
        builder.BuildInto(self)
        self.set_name("rigid_body_plant")

    def _sub_context(self, context):
        return self.GetMutableSubsystemContext(self._symbolic, context)

    def SetInertia(self, context, inertia) -> None:
        """Set the inertia (3 principal moments or 3x3, kg m^2) in ``context``.

        Raises:
            ValueError: an unphysical inertia, or a non-diagonal one on a plant built in the
                principal-axes form (build it with that inertia instead).
        """
        I = validate_inertia(inertia)
        if self.principal_axes:
            if not np.all(I == np.diag(np.diag(I))):
                raise ValueError(
                    f"inertia: got {I.tolist()}; this plant was built for principal axes (a diagonal inertia) "
                    "and takes diagonal inertias only: build the plant with a full inertia instead"
                )
            d = np.diag(I)
            c = np.array([(d[1] - d[2]) / d[0], (d[2] - d[0]) / d[1], (d[0] - d[1]) / d[2]])
            vec = np.concatenate([d, 1.0 / d, c])
        else:
            vec = np.concatenate([I.ravel(), np.linalg.inv(I).ravel()])
        self._sub_context(context).get_mutable_numeric_parameter(0).SetFromVector(vec)

    def GetInertia(self, context) -> np.ndarray:
        sub = self.GetSubsystemContext(self._symbolic, context)
        p = sub.get_numeric_parameter(0).value()
        return np.diag(p[:3]) if self.principal_axes else p[:9].reshape(3, 3)

    def SetInitialState(self, context, q_IB, w_IB_B) -> None:
        """Set attitude (normalized here) and body rate; zero the rate integral."""
        q = np.asarray(q_IB, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
            raise ValueError(f"q_IB: got {q_IB!r}; must be 4 finite numbers, not all zero")
        w = np.asarray(w_IB_B, dtype=float)
        if w.shape != (3,) or not np.all(np.isfinite(w)):
            raise ValueError(f"w_IB_B: got {w_IB_B!r}; must be 3 finite numbers (rad/s)")
        x = np.concatenate([q / np.linalg.norm(q), w, np.zeros(3)])
        self._sub_context(context).SetContinuousState(x)

    def SetDefaultParametersAndState(self, context) -> None:
        """Write the constructor's inertia into ``context`` (call once after creating it)."""
        self.SetInertia(context, self._default_inertia)

    def get_continuous_state(self, context) -> np.ndarray:
        sub = self.GetSubsystemContext(self._symbolic, context)
        return sub.get_continuous_state_vector().CopyToVector()  # type: ignore[return-value]  # pydrake stub


def _as_expression(x):
    """``Expression(x)``; pydrake 1.51 has no ``Expression(Expression)`` constructor."""
    return x if isinstance(x, Expression) else Expression(x)


def _piecewise(t, times, values):
    """Symbolic piecewise-constant: ``values[i]`` for ``times[i] <= t < times[i+1]``."""
    expr = _as_expression(values[-1])
    for i in range(len(values) - 2, -1, -1):
        expr = if_then_else(t < times[i + 1], _as_expression(values[i]), expr)
    return expr


class PrescribedAttitudeMotion(Diagram):
    """Kinematic truth: attitude integrated from a prescribed body-rate profile.

    The body rate ``w_IB_B(t)`` is a symbolic function of time; the attitude follows
    from the quaternion kinematics (integrated by Drake's integrator in C++).  Use
    :meth:`from_rate_profile` (constant + sinusoids per axis, e.g. paper S4's
    ``1e-4 cos(0.1 t)``) or :meth:`from_rpy_breakpoints` (piecewise-linear roll/pitch/yaw,
    e.g. paper S2's air-bearing-table motion), or pass expressions directly.

    Output ports:
        q_IB (4), w_IB_B (3), w_IB_B_integral (3): as :class:`RigidBodyAttitudePlant`.
    Continuous state (7): ``[q_IB (4), w_IB_B_integral (3)]``.
    """

    def __init__(self, w_of_t_expressions, time_variable: Variable, q_IB0=(1.0, 0.0, 0.0, 0.0)):
        Diagram.__init__(self)
        t = time_variable
        q = [Variable(f"q{i}") for i in range(4)]
        th = [Variable(f"theta{i}") for i in range(3)]
        w = [_as_expression(e) for e in w_of_t_expressions]
        if len(w) != 3:
            raise ValueError(f"w_of_t_expressions: got {len(w)} expressions; need 3")
        dynamics = _quat_kinematics(q, w) + list(w)
        output = list(q) + list(w) + list(th)
        self._symbolic = SymbolicVectorSystem(  # type: ignore[call-overload]  # pydrake stub
            time=t, state=q + th, dynamics=dynamics, output=output
        )
        self._q0 = np.asarray(q_IB0, dtype=float) / np.linalg.norm(q_IB0)
        builder = DiagramBuilder()
        sym = builder.AddNamedSystem("prescribed_kinematics", self._symbolic)
        demux = builder.AddNamedSystem("demux", Demultiplexer([4, 3, 3]))
        builder.Connect(sym.get_output_port(), demux.get_input_port())
        builder.ExportOutput(demux.get_output_port(0), "q_IB")
        builder.ExportOutput(demux.get_output_port(1), "w_IB_B")
        builder.ExportOutput(demux.get_output_port(2), "w_IB_B_integral")
        builder.BuildInto(self)
        self.set_name("prescribed_motion")

    def SetInitialState(self, context, q_IB=None, w_IB_B=None) -> None:
        """Set the initial attitude (``w_IB_B`` is prescribed and ignored)."""
        q = self._q0 if q_IB is None else np.asarray(q_IB, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
            raise ValueError(f"q_IB: got {q_IB!r}; must be 4 finite numbers, not all zero")
        sub = self.GetMutableSubsystemContext(self._symbolic, context)
        x = np.concatenate([q / np.linalg.norm(q), np.zeros(3)])
        sub.SetContinuousState(x)  # type: ignore[arg-type]  # pydrake stub

    def SetDefaultParametersAndState(self, context) -> None:
        self.SetInitialState(context)

    @classmethod
    def from_rate_profile(
        cls,
        constant_rad_per_s=(0, 0, 0),
        amplitude_rad_per_s=(0, 0, 0),
        frequency_rad_per_s=(0, 0, 0),
        phase_rad=(0, 0, 0),
        q_IB0=(1, 0, 0, 0),
    ):
        """``w_i(t) = c_i + A_i cos(f_i t + phi_i)`` per body axis."""
        t = Variable("t")
        from pydrake.symbolic import cos

        w = [
            float(c) + float(a) * cos(float(f) * t + float(p))
            for c, a, f, p in zip(constant_rad_per_s, amplitude_rad_per_s, frequency_rad_per_s, phase_rad, strict=True)
        ]
        return cls(w, t, q_IB0)

    @classmethod
    def from_rpy_breakpoints(cls, times_s, rpy_rad):
        """Piecewise-linear roll/pitch/yaw through ``(times_s[i], rpy_rad[i])``.

        Before the first and after the last breakpoint the angles are held constant.
        The body rate is ``w = E(rpy) rpy_dot`` (see ``rotations.rpy_rates_to_body_rate``),
        so the integrated attitude equals ``rpy_to_quat(rpy(t))`` up to integration error.
        """
        from pydrake.symbolic import cos, sin

        from drake_att import rotations as rot

        times = np.asarray(times_s, dtype=float)
        rpy = np.asarray(rpy_rad, dtype=float)
        if times.ndim != 1 or rpy.shape != (len(times), 3) or len(times) < 2:
            raise ValueError("rpy breakpoints: need times (n,) and angles (n, 3) with n >= 2")
        if np.any(np.diff(times) <= 0):
            raise ValueError(f"times_s: got {times.tolist()}; must be strictly increasing")
        t = Variable("t")
        rates = np.diff(rpy, axis=0) / np.diff(times)[:, None]
        seg_times = np.concatenate([[-np.inf], times, [np.inf]])
        angle_exprs, rate_exprs = [], []
        for axis in range(3):
            # angle(t) = rpy[i] + rate_i (t - t_i) in segment i; held outside.
            ang_vals = [Expression(rpy[0, axis])]
            rate_vals = [0.0]
            for i in range(len(times) - 1):
                ang_vals.append(rpy[i, axis] + rates[i, axis] * (t - times[i]))
                rate_vals.append(rates[i, axis])
            ang_vals.append(Expression(rpy[-1, axis]))
            rate_vals.append(0.0)
            angle_exprs.append(_piecewise(t, list(seg_times), ang_vals))
            rate_exprs.append(_piecewise(t, list(seg_times), rate_vals))
        r, p = angle_exprs[0], angle_exprs[1]
        rd, pd, yd = rate_exprs
        w = [rd - sin(p) * yd, cos(r) * pd + sin(r) * cos(p) * yd, -sin(r) * pd + cos(r) * cos(p) * yd]
        return cls(w, t, rot.rpy_to_quat(rpy[0]))
