"""Physical effects a simulated PSM joint has beyond the nominal model (eq. 4.16): `HiddenEffects`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class HiddenEffects:
    """Physical effects the nominal model (eq. 4.16) lacks; all off by default.

    Arrays are per joint (joints 1-3); units N m for joints 1-2 and N for joint 3.
    """

    stiction: np.ndarray = field(default_factory=lambda: np.zeros(3))          # breakaway level Fs (>= Fc)
    stribeck_velocity: np.ndarray = field(default_factory=lambda: np.full(3, 0.01))  # vs (rad/s, m/s)
    coulomb_asymmetry: np.ndarray = field(default_factory=lambda: np.zeros(3))  # Fc+ - Fc- (level difference)
    position_friction: np.ndarray = field(default_factory=lambda: np.zeros(3))  # relative amplitude of Fc(q)
    position_friction_period: np.ndarray = field(default_factory=lambda: np.array([0.8, 0.6, 0.08]))  # rad, m
    spring: np.ndarray = field(default_factory=lambda: np.zeros(3))            # stiffness k (N m/rad, N/m)
    spring_rest: np.ndarray = field(default_factory=lambda: np.zeros(3))       # q0 where the spring is relaxed
    payload_mass: float = 0.0                                                  # kg on the tool
    payload_com: np.ndarray = field(default_factory=lambda: np.zeros(3))       # m, tool joint frame
    backlash: np.ndarray = field(default_factory=lambda: np.zeros(3))          # total play (rad, m)
    # Inertia on the motor side of a play (N m s^2/rad, kg); NaN: half the rotor inertia Ia.
    backlash_motor_inertia: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    time_delay: float | np.ndarray = 0.0                                       # s, measured effort behind the motion (one or per joint)
    torque_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))     # constant load on the joint
    viscous_nonlinear: np.ndarray = field(default_factory=lambda: np.zeros(3))  # c in c sign(dq) |dq|^n
    viscous_exponent: np.ndarray = field(default_factory=lambda: np.full(3, 2.0))  # n of that law
    # An absolute Coulomb-level profile f(q) = sum_k s_k sin(2 pi k q / P) + c_k cos(2 pi k q / P),
    # k = 1..4 (N m, N), over the period P (rad, m; 0 = none): a model file's position_friction.
    friction_profile_period: np.ndarray = field(default_factory=lambda: np.zeros(3))
    friction_profile_sin: np.ndarray = field(default_factory=lambda: np.zeros((3, 4)))   # (joint, k)
    friction_profile_cos: np.ndarray = field(default_factory=lambda: np.zeros((3, 4)))
    hysteresis: np.ndarray = field(default_factory=lambda: np.zeros(3))        # Dahl level Fd (0 = off)
    hysteresis_stiffness: np.ndarray = field(default_factory=lambda: np.array([40.0, 40.0, 400.0]))  # sigma0
