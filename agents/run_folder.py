"""The file names of a run folder, shared by ``tl-gym train``/``eval`` and the benchmark runner.

The command line reads the runner's folders (``tl-gym eval runs/<run_id>``) and cannot import the benchmarks,
so the names both write live here, below both.
"""

#: One row per iteration (`tl_gym.agents.callbacks.HistoryCSV`), written by both.
HISTORY_FILE = "history.csv"
#: The final agent (`Agent.save`), written by both.
AGENT_FILE = "agent.zip"
#: The experiment runner's description of a run (a `benchmarks.sweep_config.RunSpec`).
RUNNER_SPEC_FILE = "spec.json"
#: The experiment runner's mark of a finished run, with its summary (git keeps it, not the agent).
RUNNER_DONE_FILE = "done.json"
