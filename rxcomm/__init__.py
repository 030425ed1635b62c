"""rxcomm: commissioning pipeline for 6-axis industrial robots.

The library is organised by concept (robot model, kinematics, dynamics, optimisation, gateway,
simulated cell, I/O); ``rxcomm.stages`` holds the thin command stages and ``rxcomm.schemas`` the
artefact contracts. Dependencies point one way: stages -> library + schemas.
"""

import os as _os

# Our matrices are at most a few hundred × ~100: BLAS threads only add contention on a shared
# 2-core machine (a 30×30 eigh went from 0.24 ms to 21 ms). Effective when rxcomm is imported
# before numpy, as in the CLI; an explicit setting by the user wins.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
