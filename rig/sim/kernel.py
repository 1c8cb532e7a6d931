"""The compiled inner step of the simulated rig (numba).

Pinocchio gives the tree's mass matrix and bias forces; everything else of a 1 ms step
(projection by G, controllers, object forces, friction impulses, integration) happens
here, in one compiled call, so the rig runs far faster than real time from Python.
`rig.sim.world.SimWorld` owns the state; this module holds only arithmetic.
"""

from __future__ import annotations

import numpy as np
from numba import njit

MODE_OFF, MODE_POSITION, MODE_EFFORT = 0, 1, 2


@njit(cache=True)
def tip_and_jacobian(q, base, r_offset):
    """Tip position (world) and 3x3 translational Jacobian from the dVRK closed form.

    `base` is the 4x4 RCM frame in the world; r = q3 + r_offset is the distance past the RCM.
    """
    q1, q2, q3 = q[0], q[1], q[2]
    r = q3 + r_offset
    c1, s1, c2, s2 = np.cos(q1), np.sin(q1), np.cos(q2), np.sin(q2)
    p = np.empty(3)
    p[0] = c2 * s1 * r
    p[1] = -s2 * r
    p[2] = -c1 * c2 * r
    J = np.empty((3, 3))
    J[0, 0] = c2 * c1 * r
    J[0, 1] = -s2 * s1 * r
    J[0, 2] = c2 * s1
    J[1, 0] = 0.0
    J[1, 1] = -c2 * r
    J[1, 2] = -s2
    J[2, 0] = c2 * s1 * r
    J[2, 1] = c1 * s2 * r
    J[2, 2] = -c1 * c2
    R = np.ascontiguousarray(base[:3, :3])
    pw = base[:3, 3] + R @ p
    return pw, R @ J


# Rows of the constants array passed to `step` (one column per joint of the rig).
CONSTANT_ROWS = ("Ij", "Im", "Fc", "Fs", "vs", "asym", "posfric", "period", "Fv", "Fo", "offset",
                 "kspring", "qspring", "visc2", "dahl_level", "dahl_sigma", "backlash", "kp", "kd",
                 "ki", "ilim", "effort_limit", "quantum", "backlash_k", "backlash_c", "visc_exp",
                 "profile_period", "profile_sin1", "profile_sin2", "profile_sin3", "profile_sin4",
                 "profile_cos1", "profile_cos2", "profile_cos3", "profile_cos4")
#: Harmonics of the absolute friction profile (rows profile_sin*/profile_cos*).
PROFILE_HARMONICS = 4
# Rows of the state array (updated in place).
STATE_ROWS = ("q", "dq", "qm", "dqm", "dahl", "q_des", "dq_des", "integral", "tau_cmd", "tau_applied")


@njit(cache=True)
def step(h, Mt, nle, G, state, c, modes, edges, rest, obj, bases, r_offset, tensions):
    """One time step of every arm. `c`: CONSTANT_ROWS x 3N, `state`: STATE_ROWS x 3N,
    `obj` = (stiffness N/m, damping N s/m, 1.0 for a string else 0.0).

    A joint's Coulomb level is Fc (1 + posfric sin(2 pi q / period)) (the relative ripple of a
    hidden effect) plus an absolute profile sum_k s_k sin(2 pi k q / P) + c_k cos(2 pi k q / P)
    over profile_period P (0: none; a model file's position-dependent friction). The smooth
    load's c sign(dq) |dq|^n has exponent n = visc_exp."""
    q, dq, qm, dqm, dahl = state[0], state[1], state[2], state[3], state[4]
    q_des, dq_des, integral, tau_cmd, tau_applied = state[5], state[6], state[7], state[8], state[9]
    (Ij, Im, Fc, Fs, vs, asym, posfric, period, Fv, Fo, offset, kspring, qspring, visc2,
     dahl_level, dahl_sigma, backlash, kp, kd, ki, ilim, effort_limit, quantum,
     backlash_k, backlash_c, visc_exp, profile_period) = (
        c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], c[13],
        c[14], c[15], c[16], c[17], c[18], c[19], c[20], c[21], c[22], c[23], c[24], c[25], c[26])
    profile_sin, profile_cos = c[27:31], c[31:35]
    stiffness, damping, string = obj[0], obj[1], obj[2] > 0.5
    n3 = q.shape[0]
    n_arms = n3 // 3
    nv = Mt.shape[0]
    # Mass matrix (crba fills the upper triangle) projected by G, plus the rotor inertia.
    for i in range(nv):
        for j in range(i):
            Mt[i, j] = Mt[j, i]
    M = G.T @ Mt @ G
    for i in range(n3):
        M[i, i] += Ij[i]
    bias = G.T @ nle

    # Controllers: the dVRK joint PID on the encoder reading, or a direct effort.
    tau = np.zeros(n3)
    for a in range(n_arms):
        for j in range(3 * a, 3 * a + 3):
            if modes[a] == MODE_POSITION:
                meas = qm[j]
                if quantum[j] > 0.0:
                    meas = np.round(meas / quantum[j]) * quantum[j]
                err = q_des[j] - meas
                integral[j] = min(max(integral[j] + err * h * ki[j], -ilim[j]), ilim[j])
                tau[j] = kp[j] * err + kd[j] * (dq_des[j] - dqm[j]) + integral[j]
            elif modes[a] == MODE_EFFORT:
                tau[j] = tau_cmd[j]
            tau[j] = min(max(tau[j], -effort_limit[j]), effort_limit[j])
            tau_applied[j] = tau[j]

    # Object: spring-damper elements between tips (eq. 6.1); tension pulls the tips together.
    ext = np.zeros(n3)
    for k in range(edges.shape[0]):
        a, b = edges[k, 0], edges[k, 1]
        pa, Ja = tip_and_jacobian(q[3 * a:3 * a + 3], bases[a], r_offset)
        pb, Jb = tip_and_jacobian(q[3 * b:3 * b + 3], bases[b], r_offset)
        v = pb - pa
        length = np.sqrt(v @ v)
        u = v / max(length, 1e-9)
        rate = u @ (Jb @ dq[3 * b:3 * b + 3] - Ja @ dq[3 * a:3 * a + 3])
        t = stiffness * (length - rest[k]) + damping * rate
        if string and (length <= rest[k] or t < 0.0):
            t = 0.0
        tensions[k] = t
        fa = Ja.T @ (t * u)
        fb = Jb.T @ (-t * u)
        for i in range(3):
            ext[3 * a + i] += fa[i]
            ext[3 * b + i] += fb[i]

    # Smooth joint-side loads and the drive torque through any backlash.
    rhs = np.empty(n3)
    coupling = np.zeros(n3)
    stretch = np.zeros(n3)
    contact = np.zeros(n3, dtype=np.bool_)
    has_backlash = False
    for j in range(n3):
        smooth = Fv[j] * dq[j] + Fo[j] + offset[j] + kspring[j] * (q[j] - qspring[j])
        if visc2[j] != 0.0:
            if visc_exp[j] == 2.0:
                smooth += visc2[j] * dq[j] * abs(dq[j])
            else:
                smooth += visc2[j] * np.sign(dq[j]) * abs(dq[j]) ** visc_exp[j]
        if dahl_level[j] > 0.0:
            dx = dq[j] * h
            target = np.sign(dx) * dahl_level[j]
            dahl[j] = target + (dahl[j] - target) * np.exp(-dahl_sigma[j] * abs(dx) / dahl_level[j])
            smooth += dahl[j]
        drive = tau[j]
        if backlash[j] > 0.0:
            has_backlash = True
            gap = 0.5 * backlash[j]
            d = qm[j] - q[j]
            if d > gap:
                stretch[j] = d - gap
                contact[j] = True
            elif d < -gap:
                stretch[j] = d + gap
                contact[j] = True
            drive = 0.0   # the transmitted torque is solved for below
        rhs[j] = drive + ext[j] - bias[j] - smooth

    Minv = np.linalg.inv(M)
    v = dq + h * (Minv @ rhs)
    if has_backlash:
        # The contact spring-damper between the motor side and the joint side of each play,
        # linearly implicit in the new relative velocity w+ = dqm+ - dq+ (backward Euler on the
        # pair: F = k stretch + (c + h k) w+). Explicit, c h / Im > 1 made the motor side
        # chatter; implicit, the contact is dissipative for any stiffness and damping.
        # w+ = w_free - h (Im^-1 + Minv) F, and F = F0 + D w+ on the joints in contact:
        # (I + h D A) F = F0 + D w_free.
        A = Minv.copy()
        w_free = np.zeros(n3)
        F0 = np.zeros(n3)
        D = np.zeros(n3)
        for j in range(n3):
            if backlash[j] > 0.0:
                A[j, j] += 1.0 / Im[j]
                w_free[j] = dqm[j] + h * tau[j] / Im[j] - v[j]
                if contact[j]:
                    F0[j] = backlash_k[j] * stretch[j]
                    D[j] = backlash_c[j] + h * backlash_k[j]
        S = np.eye(n3)
        b = np.zeros(n3)
        for j in range(n3):
            if D[j] > 0.0:
                for i in range(n3):
                    S[j, i] += h * D[j] * A[j, i]
                b[j] = F0[j] + D[j] * w_free[j]
        F = np.linalg.solve(S, b)
        for j in range(n3):
            coupling[j] = F[j]
        v += h * (Minv @ F)

    # Dry friction: impulses bounded by the Coulomb/Stribeck level, projected Gauss-Seidel.
    up = np.empty(n3)
    down = np.empty(n3)
    for j in range(n3):
        fc = Fc[j] * (1.0 + posfric[j] * np.sin(2.0 * np.pi * q[j] / period[j]))
        if profile_period[j] > 0.0:
            x = 2.0 * np.pi * q[j] / profile_period[j]
            for k in range(PROFILE_HARMONICS):
                fc += profile_sin[k, j] * np.sin((k + 1) * x) + profile_cos[k, j] * np.cos((k + 1) * x)
        level = fc
        excess = Fs[j] - Fc[j]
        if excess > 0.0:
            # The Stribeck level at the speed the joint slides with after this step's friction
            # impulse: slip = |v| - h Minv_jj level(slip) (0 if that sticks it). Taken at the
            # predicted |v| instead, the step's own friction (h level / M, a fraction of vs on
            # the insertion axis at 1 kHz) shifted the curve, and the plant's stiction was not
            # the law its parameters state.
            side = fc + (0.5 if v[j] > 0.0 else -0.5) * asym[j]
            gain = h * Minv[j, j]
            speed = abs(v[j])
            slip = 0.0
            if speed > gain * (side + excess):
                lo, hi = 0.0, speed
                for _ in range(40):
                    slip = 0.5 * (lo + hi)
                    s = slip / vs[j]
                    if slip - speed + gain * (side + excess * np.exp(-s * s)) > 0.0:
                        hi = slip
                    else:
                        lo = slip
            s = slip / vs[j]
            level = fc + excess * np.exp(-s * s)
        up[j] = max(h * (level + 0.5 * asym[j]), 0.0)
        down[j] = max(h * (level - 0.5 * asym[j]), 0.0)
    p = np.zeros(n3)
    for _ in range(6):
        for j in range(n3):
            if up[j] == 0.0 and down[j] == 0.0:
                continue
            target = p[j] - v[j] / Minv[j, j]
            new = min(max(target, -up[j]), down[j])
            dp = new - p[j]
            if dp != 0.0:
                for i in range(n3):
                    v[i] += Minv[i, j] * dp
                p[j] = new

    for j in range(n3):
        dq[j] = v[j]
        q[j] += h * v[j]
        if backlash[j] > 0.0:
            dqm[j] += h * (tau[j] - coupling[j]) / Im[j]
            qm[j] += h * dqm[j]
        else:
            dqm[j] = dq[j]
            qm[j] = q[j]
