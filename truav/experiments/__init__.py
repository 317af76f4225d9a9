"""The paper's experiments: the velocity sweep and the scalability study (the command line: truav/cli/experiment.py)."""
