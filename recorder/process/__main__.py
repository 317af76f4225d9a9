"""``python -m recorder.process``: the recorder process, the spelling before truav.cli.log_process (the same command)."""
import runpy

runpy.run_module("truav.cli.log_process", run_name="__main__", alter_sys=True)
