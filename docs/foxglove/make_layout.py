"""Writes rxcomm-layout.json beside this file with the official foxglove-sdk's layout model.

Not part of the package (foxglove-sdk is no dependency of rxcomm): run it with an environment that
has it, `pip install foxglove-sdk`, after changing a panel, and commit the JSON. The channel names
are the run-log contract (rxcomm/schemas/run_log.py); tests/test_foxglove_log.py checks that every
topic the layout names exists in a run log.
"""

from pathlib import Path

import foxglove.layouts as fl

JOINTS = "/run/joints"
N_JOINTS = 6


def _plot(title: str, series: list[tuple[str, str]]) -> fl.PlotPanel:
    paths = [fl.PlotSeries(value=v, label=label, timestamp_method="receiveTime") for v, label in series]
    return fl.PlotPanel(
        title=title, config=fl.PlotConfig(paths=paths, show_legend=True, legend_display="top")
    )


def _per_joint(field: str, unit: str) -> list[tuple[str, str]]:
    return [(f"{JOINTS}.{field}[{i}]", f"J{i + 1} {field} ({unit})") for i in range(N_JOINTS)]


def _urdf(label: str, prefix: str | None, opacity: float, order: int) -> fl.BaseRendererUrdfLayerSettings:
    return fl.BaseRendererUrdfLayerSettings(
        label=label,
        order=order,
        visible=True,
        source_type="topic",
        topic="/robot_description",
        frame_prefix=prefix,
        control_mode="transforms",
        show_axis=True,
        axis_scale=0.15,
        opacity=opacity,
    )


def layout() -> fl.Layout:
    three_d = fl.ThreeDeePanel(
        title="Robot: actual (URDF) and demand (demand/ frames), TCP poses",
        config=fl.ThreeDeeConfig(
            follow_tf="base_link",
            layers={
                "urdf-actual": _urdf("robot, actual joints", None, 1.0, 1),
                "urdf-demand": _urdf("robot, demanded joints", "demand/", 0.35, 2),
            },
            topics={
                "/run/tcp": fl.BaseRendererPoseTopicSettings(visible=True, type="axis", axis_scale=0.2),
                "/run/tcp_demand": fl.BaseRendererPoseTopicSettings(visible=True, type="arrow"),
            },
        ),
    )
    plots = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=_plot("Following error (rad)", _per_joint("following_error", "rad"))),
            fl.SplitItem(content=_plot("Torque actual (N·m)", _per_joint("tau_actual", "N·m"))),
            fl.SplitItem(content=_plot("Torque feed-forward (N·m)", _per_joint("tau_ff", "N·m"))),
            fl.SplitItem(
                content=_plot(
                    "TCP speed (m/s) and TCP error (m)",
                    [
                        (f"{JOINTS}.tcp_speed_m_s", "TCP speed (m/s)"),
                        (f"{JOINTS}.tcp_error_m", "TCP error (m)"),
                    ],
                )
            ),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=3, content=plots), fl.SplitItem(proportion=2, content=three_d)],
        )
    )


if __name__ == "__main__":
    import json

    out = Path(__file__).with_name("rxcomm-layout.json")
    out.write_text(json.dumps(json.loads(layout().to_json()), indent=1, ensure_ascii=False) + "\n")
    print(out)
