"""Energy figures (rxcomm.model.energy) against analytic cases."""

from dataclasses import replace

import numpy as np
import pytest

from rxcomm.model.energy import electrical_energy, electrical_power, motion_energy, torque_squared_integral


def test_torque_squared_integral_of_a_sine_and_a_constant():
    t = np.linspace(0.0, 2.0, 20001)  # two periods of 1 Hz
    tau = np.zeros((len(t), 6))
    tau[:, 1] = 30.0 * np.sin(2 * np.pi * t)
    tau[:, 4] = 2.0
    # ∫(A sin)² over whole periods = A² T / 2; a constant c gives c² T
    assert torque_squared_integral(t, tau) == pytest.approx(30.0**2 * 2.0 / 2 + 2.0**2 * 2.0, rel=1e-6)
    tau[5, 1] = np.nan  # a lost record is left out, not counted as zero
    assert torque_squared_integral(t, tau) == pytest.approx(30.0**2 + 8.0, rel=1e-4)


def test_electrical_energy_of_one_axis_at_constant_speed_and_torque(m900):
    """Joint 2 lifts at q̇ = 0.5 rad/s against τ = 40 N·m for 2 s: τ_m = τ/N, ω_m = N·q̇,
    E = (τ·q̇ + R·(τ/(N·k_t))²)·T."""
    n, big_n = m900.gear_ratio[1], 2.0
    kt, r = m900.torque_constant[1], m900.drives.joints[1].winding_resistance_ohm
    t = np.linspace(0.0, big_n, 401)
    qd = np.zeros((len(t), 6))
    qd[:, 1] = 0.5
    tau = np.zeros((len(t), 6))
    tau[:, 1] = 40.0
    expected = (40.0 * 0.5 + r * (40.0 / (n * kt)) ** 2) * big_n
    assert electrical_energy(m900, t, qd, tau) == pytest.approx(expected, rel=1e-9)
    # braking beyond the copper loss (bus power negative) is burnt in the brake resistor, not returned
    p_brake = electrical_power(m900, -qd, tau)
    assert np.all(p_brake < 0)
    assert electrical_energy(m900, t, -qd, tau) == 0.0
    # from positions: a ramp q2 = 0.5 t gives the same speed
    q = np.zeros((len(t), 6))
    q[:, 1] = 0.5 * t
    e = motion_energy(m900, t, q, tau)
    assert e["electrical_energy_j"] == pytest.approx(expected, rel=1e-9)
    assert e["tau_squared_integral_nm2_s"] == pytest.approx(40.0**2 * big_n)


def test_coupled_wrist_motor_currents(rx130l):
    """RX130L motor 6 turns at 40·(q̇6 + 0.4·q̇5): a torque on joint 5 alone with joint 6 held needs
    motor 6 to hold too (τ = Rᵀ·τ_m); the copper loss counts both motors."""
    tau = np.zeros((1, 6))
    tau[0, 4] = 10.0
    p = electrical_power(rx130l, np.zeros((1, 6)), tau)[0]
    r = rx130l.joint_to_motor
    tau_m = np.linalg.solve(r.T, tau[0])
    assert tau_m[5] == pytest.approx(0.0) and tau_m[4] == pytest.approx(10.0 / 100)
    res = np.array([j.winding_resistance_ohm for j in rx130l.drives.joints])
    assert p == pytest.approx(float(np.sum(res * (tau_m / rx130l.torque_constant) ** 2)))
    tau[0, 4], tau[0, 5] = 0.0, 4.0  # a torque on joint 6 loads motor 6 and, through Rᵀ, joint 5 too
    tau_m = np.linalg.solve(r.T, tau[0])
    assert tau_m[5] == pytest.approx(4.0 / 40) and tau_m[4] == pytest.approx(-0.4 * 4.0 / 100)


def test_no_winding_resistance_is_not_measured(m900):
    joints = [j.model_copy(update={"winding_resistance_ohm": None}) for j in m900.drives.joints]
    bare = replace(m900, drives=m900.drives.model_copy(update={"joints": joints}))
    t = np.linspace(0, 1, 11)
    assert electrical_energy(bare, t, np.zeros((11, 6)), np.ones((11, 6))) is None
