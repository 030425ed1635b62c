"""The simulated cell: the stand-in for a real robot, its drives, gateway server and tracker.

Its hidden truth (``truth.yaml``) is read here and nowhere else in the library; stages and the
other packages talk to it only through the gateway protocol and the tracker's measurements.

The gateway side of map v1 (docs/gateway.md): ``gateway_machine`` (drives, stream phases, stops, the
drive cycle) and its buffers in ``rings``; ``gateway_core`` with ``register_writes`` and
``register_images`` (the register map on top); ``server`` (pymodbus and the clock). The physics behind
it: ``backend`` (the interface), ``sim`` (drives, plant, tracker from a truth file).

May import: `rxcomm.model`, `rxcomm.gateway`, `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`.
Never calibration, identification, planning or execution (see docs/architecture.md).
"""
