"""`rxcomm cell-sim --truth TRUTH.yaml`: the simulated cell on the drive gateway protocol (architecture §6).

A Modbus TCP server (register map v1, docs/gateway.md) in front of six simulated drives moving the
robot of the truth file with its true dynamics, plus the simulated tracker. Runs until Ctrl-C (or
SIGTERM, or `--duration-s`), then stops cleanly.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from rxcomm import console
from rxcomm.errors import InputError
from rxcomm.options import CellFile, Plant, parse_numbers, radians_text

if TYPE_CHECKING:  # the cell (pinocchio, the plant) is imported where used: `--help` stays fast
    from rxcomm.cell.server import CellServer
    from rxcomm.cell.sim import SimulatedCell


def command(
    truth: Annotated[
        Path,
        typer.Option(help="The cell's hidden truth (truth.yaml): robot, true dynamics, errors, noise."),
    ],
    host: Annotated[
        str, typer.Option(help="Address to listen on (loopback unless --allow-remote).")
    ] = "127.0.0.1",
    port: Annotated[
        int, typer.Option(help="TCP port; 0 picks a free one (printed).", min=0, max=65535)
    ] = 1502,
    realtime: Annotated[
        bool, typer.Option(help="Pace drive cycles by the wall clock (demos); default: virtual time.")
    ] = False,
    q0: Annotated[
        str | None,
        typer.Option("--start", help="Initial joint angles 'q1,…,q6' (rad); default all zero (arm upright)."),
    ] = None,
    q0_deg: Annotated[
        str | None, typer.Option("--start-deg", help="Initial joint angles in degrees.")
    ] = None,
    cell: CellFile = None,  # the tracker's field of view (default: cell.yaml beside the truth)
    seed: Annotated[int | None, typer.Option(help="Noise seed (default: the truth file's).")] = None,
    duration_s: Annotated[
        float | None,
        typer.Option("--duration-s", help="Stop after this many seconds (default: until Ctrl-C)."),
    ] = None,
    allow_remote: Annotated[
        bool,
        typer.Option(help="Allow listening on a non-loopback address (anyone there can move the robot)."),
    ] = False,
    plant: Plant = "own",
) -> None:
    """Serve the simulated robot cell (drives, true dynamics, tracker) as a Modbus TCP drive gateway.

    --cell: the tracker's field of view (default: the cell.yaml beside the truth)."""
    q0 = console.checked(radians_text, q0, q0_deg, "start")
    run(
        truth,
        host=host,
        port=port,
        realtime=realtime,
        q0=q0,
        cell=cell,
        seed=seed,
        duration_s=duration_s,
        allow_remote=allow_remote,
        plant=plant,
    )


@console.stage_command
def run(
    truth: Path,
    *,
    host: str = "127.0.0.1",
    port: int = 1502,
    realtime: bool = False,
    q0: str | None = None,
    cell: Path | None = None,
    seed: int | None = None,
    duration_s: float | None = None,
    allow_remote: bool = False,
    plant: str = "own",
    on_ready: Callable[[dict[str, object]], None] | None = None,
    stop: threading.Event | None = None,
) -> dict[str, object]:
    """The stage as a function: serve until `stop` is set, Ctrl-C/SIGTERM, or `duration_s`; returns the
    facts printed at start-up, which `on_ready` also receives once the server listens."""
    from rxcomm.cell.server import CellServer, ServerConfig, TimeMode
    from rxcomm.cell.sim import SimSettings, cell_class
    from rxcomm.cell.truth import load_truth
    from rxcomm.gateway.net import is_loopback

    if not is_loopback(host) and not allow_remote:
        raise InputError(f"{host} is not a loopback address: pass --allow-remote to serve it", field="--host")
    if duration_s is not None and not duration_s > 0:
        raise InputError("must be positive", field="--duration-s")
    backend_class = cell_class(plant)  # an unknown plant fails before the truth is read
    sim_truth = load_truth(truth, cell)
    settings = SimSettings(
        q0_rad=None if q0 is None else tuple(parse_numbers(q0, sim_truth.robot.n, "--start", "rad")),
        seed=seed,
    )
    backend = backend_class(sim_truth, settings)
    config = ServerConfig(
        host=host,
        port=port,
        time_mode=TimeMode.REALTIME if realtime else TimeMode.VIRTUAL,
        allow_remote=allow_remote,
    )
    server = CellServer(backend, config).start()
    stop = stop or threading.Event()
    restore = _stop_on_sigterm(stop)
    try:
        facts = _facts(server, backend)
        _print_facts(facts)
        if on_ready is not None:
            on_ready(facts)
        deadline = None if duration_s is None else time.monotonic() + duration_s
        try:
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                stop.wait(0.1 if deadline is None else max(0.0, min(0.1, deadline - time.monotonic())))
        except KeyboardInterrupt:
            console.err.print("interrupted: stopping the cell")
    finally:
        server.stop()
        restore()
    console.out.print(f"cell stopped after {backend.cycles} drive cycles")
    return facts


def _stop_on_sigterm(stop: threading.Event):
    """SIGTERM stops the server like Ctrl-C (only the main thread may install handlers)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return lambda: signal.signal(signal.SIGTERM, previous)


def _facts(server: CellServer, cell: SimulatedCell) -> dict[str, object]:
    t = cell.truth
    g = cell.gains
    return {
        "address": f"{server.host}:{server.port}",
        "time_mode": str(server.config.time_mode),
        "robot": t.robot.name,
        "plant": cell.plant_name,
        "plant_notes": list(cell.plant_notes),
        "truth": str(t.path),
        "cell": None if t.cell_path is None else str(t.cell_path),
        "n_axes": cell.n_axes,
        "cycle_us": round(cell.cycle_s * 1e6),
        "buffer_capacity_cycles": server.config.buffer_capacity_cycles,
        "trace_capacity_records": server.config.trace_capacity_records,
        "watchdog_ms": server.config.watchdog_ms,
        "q0_rad": cell.plant.q.tolist(),
        "rated_torque_nm": cell.rated_torque_nm.tolist(),
        "peak_torque_nm": g.peak_torque_nm.tolist(),
        "following_error_limit_rad": g.following_error_limit_rad.tolist(),
        "quick_stop_decel_rad_s2": g.quick_stop_decel_rad_s2.tolist(),
        "velocity_loop_bandwidth_rad_s": g.velocity_bandwidth_rad_s,
        "position_gain_per_s": g.kv_per_s.tolist(),
    }


def _print_facts(f: dict[str, object]) -> None:
    out = console.out
    out.print(f"[bold]simulated cell[/] listening on {f['address']}  (Modbus TCP, register map v1)")
    out.print(f"  robot        {f['robot']}  (truth {f['truth']})")
    out.print(f"  plant        {f['plant']}")
    for note in f["plant_notes"]:  # what this plant cannot model faithfully, never dropped silently
        out.print(f"    not faithful: {note}")
    out.print(f"  tracker view {f['cell'] or 'unrestricted (no cell file)'}")
    out.print(f"  time         {f['time_mode']}, drive cycle {f['cycle_us']} µs")
    out.print(
        f"  buffers      {f['buffer_capacity_cycles']} setpoints, "
        f"{f['trace_capacity_records']} trace records; "
        f"watchdog {f['watchdog_ms']} ms at power-on"
    )
    out.print(f"  q0           {np.round(f['q0_rad'], 4).tolist()} rad")
    out.print(f"  rated torque {np.round(f['rated_torque_nm'], 1).tolist()} N·m (torque LSB = 0.1 % of it)")
    out.print(
        f"  drives       velocity loop {f['velocity_loop_bandwidth_rad_s']:.0f} rad/s, position gain "
        f"{f['position_gain_per_s'][0]:.0f} /s, following-error trip "
        f"{np.round(f['following_error_limit_rad'], 4).tolist()} rad"
    )
    out.print("  Ctrl-C stops it.")
