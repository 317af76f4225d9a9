"""The paper's experiments: the velocity sweep and the scalability study (see cli.py)."""
