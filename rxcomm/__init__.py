"""rxcomm: commissioning pipeline for 6-axis industrial robots.

The library is organised by concept (robot model, kinematics, dynamics, optimisation, gateway,
simulated cell, I/O); ``rxcomm.stages`` holds the thin command stages and ``rxcomm.schemas`` the
artefact contracts. Dependencies point one way: stages -> library + schemas.
"""

__version__ = "0.1.0"
