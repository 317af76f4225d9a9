"""The swarm's orchestration: `truav-swarm` CLI, supervisor, run-time fault control, chaos runs, plots (the process lifecycle is truav/lifecycle.py)."""
