"""The simulated cell: the stand-in for a real robot, its drives, gateway server and tracker.

Its hidden truth (``truth.yaml``) is read here and nowhere else in the library; stages and the
other packages talk to it only through the gateway protocol and the tracker's measurements.

May import: `rxcomm.model`, `rxcomm.gateway`, `rxcomm.io`, `rxcomm.schemas`, `rxcomm.errors`.
Never calibration, identification, planning or execution (see docs/architecture.md).
"""
