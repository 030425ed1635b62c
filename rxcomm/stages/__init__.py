"""One module per subcommand: options → settings model → one library call → write (architecture §2).

A stage imports the library (the paper's steps, the model, the cell; scipy, pinocchio, casadi, toppra,
matplotlib) inside the functions that run it, not at the top: `rxcomm STAGE --help` then answers from
the options alone, in ~0.5 s of CPU instead of ~2 s (tests/test_cli_vocabulary.py checks it). Names
needed only for annotations are imported under `TYPE_CHECKING`.
"""
