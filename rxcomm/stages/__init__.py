"""One module per subcommand: options → settings model → one library call → write (architecture §2).

A stage writes its options once: where a function beside the command would only forward them, the
typer `command` is the stage function tests call (architecture §2). `stages.summary` is not a
subcommand: it holds the trajectory summary head the plan stages share; nor is `stages.stage_cli`,
which makes a stage's typer command from its declaration (`stages.declarations`).

A stage imports the library (the paper's steps, the model, the cell; scipy, pinocchio, casadi, toppra,
matplotlib) inside the functions that run it, not at the top: `rxcomm STAGE --help` then answers from
the options alone, in ~0.5 s of CPU instead of ~2 s (tests/test_cli_vocabulary.py checks it). Names
needed only for annotations are imported under `TYPE_CHECKING`.
"""
