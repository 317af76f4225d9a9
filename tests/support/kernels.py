"""The numba specializations the test suite meets beyond the commands' (truav.analysis.warmup.compile_kernels):
tests/conftest.py compiles both before the workers start, in two processes side by side."""

from __future__ import annotations


def compile_test_kernels() -> None:
    """The 3GPP channel model's rates, channel-driven links, the world step of a swarm under that model and
    the central scheme's control-plane model."""
    from truav.analysis.trainer import run_chunk
    from truav.config import Config
    from world.process.world_process import warm_up_kernels
    cfg = Config().replace(scenario={"n_vehicles": 40, "steps_per_episode": 3}, roads={"warmup_steps": 3})
    uma = cfg.replace(channel={"model": "3gpp-uma-av"})
    run_chunk("truav", uma, [0], 1)
    run_chunk("truav", cfg.replace(links={"model": "channel"}), [0], 1)
    warm_up_kernels(uma)
    warm_up_kernels(cfg, central=True)
