"""The agents: learners, decisions and the agent API (their kernels set numba's cache up themselves:
truav.kernel_cache, imported by each module with kernels, so a module without any imports no numba)."""
