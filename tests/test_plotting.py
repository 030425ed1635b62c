"""Figures that show what binds: every limit as value/limit within ±1, the binding ones named, the others
faded, the legend outside the data; the excitation figure normalises by the bounds the design obeyed."""

import numpy as np

from rxcomm import plotting
from rxcomm.io.trajectory import Trajectory
from rxcomm.schemas.excitation import ExcitationSettings
from rxcomm.stages.excite import design_ratios


def test_limit_panel_names_the_binding_series_fades_the_others_and_keeps_the_legend_outside():
    plt = plotting.pyplot()
    t = np.linspace(0.0, 1.0, 200)
    ratios = {
        "velocity": np.stack([0.95 * np.sin(2 * np.pi * t), 0.5 * np.cos(2 * np.pi * t)], axis=1),
        "acceleration": np.stack([0.99 * np.sign(np.sin(2 * np.pi * t)), 0.2 * t], axis=1),
    }
    fig, ax = plt.subplots()
    binding = plotting.limit_panel(ax, t, ratios, ["joint_1", "joint_4"])
    assert binding == ["velocity joint_1 (peak 0.950)", "acceleration joint_1 (peak 0.990)"]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    faded = [ln for ln in ax.get_lines() if ln.get_color() == "0.6" and len(ln.get_xdata()) == len(t)]
    assert len(faded) == 2 and all(ln.get_alpha() < 0.5 for ln in faded)  # J4's velocity, acceleration
    assert "other limits (peak < 0.9), faded" in lines
    assert ax.get_ylim() == (-1.1, 1.1)
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.x0 > ax.get_window_extent().x1  # right of the axes: it covers no data
    plt.close(fig)


def test_signed_ratios_take_the_sign_of_the_value():
    r = {"velocity": np.array([[0.5, 0.2]]), "tcp_speed": np.array([[0.3]])}
    out = plotting.signed_ratios(r, {"velocity": np.array([[-1.0, 2.0]])})
    np.testing.assert_allclose(out["velocity"], [[-0.5, 0.2]])
    np.testing.assert_allclose(out["tcp_speed"], [[0.3]])  # no raw value: the magnitude


def test_excitation_ratios_are_against_the_design_bounds_not_the_robot_limits(rx130l):
    n = rx130l.n
    t = np.linspace(0.0, 1.0, 50)
    q = np.tile((rx130l.q_min + rx130l.q_max) / 2, (50, 1))
    qd = np.tile(0.5 * rx130l.v_max, (50, 1))
    qdd = np.tile(-0.4 * rx130l.a_max, (50, 1))
    tau = np.tile(0.4 * rx130l.tau_max, (50, 1))
    opts = ExcitationSettings(torque_fraction=0.8, velocity_fraction=0.5, acceleration_fraction=0.8)
    r = design_ratios(rx130l, Trajectory(t, q, qd, qdd, tau), opts, None)
    np.testing.assert_allclose(r["torque"], 0.5)  # 0.4·τ_peak is half the 0.8·τ_peak bound used
    np.testing.assert_allclose(r["velocity"], 1.0)
    np.testing.assert_allclose(r["acceleration"], -0.5)
    np.testing.assert_allclose(r["position"], 0.0, atol=1e-12)
    assert r["torque_rate"].shape == (50, n) and not any(k.startswith("region") for k in r)
