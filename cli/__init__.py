"""The ``tl-gym`` command line (``tl_gym.cli``), above the agents: train, evaluate, watch.

`main` is the console script; `arguments` reads the command line, `commands` runs it
(see `tl_gym.cli.commands` for the run folder it writes).
"""

from .arguments import build_parser, parse_hyperparameters, parse_signals, parse_value
from .commands import agent_for_run, build_env, main

__all__ = [
    "agent_for_run", "build_env", "build_parser", "main", "parse_hyperparameters", "parse_signals", "parse_value",
]
