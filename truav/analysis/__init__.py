"""In-process runs and their files: the episode driver, the batched trainer, kernel warm-up, run files, agent classes by name, SUMO traffic for a world, the PettingZoo adapter and figures. No bus."""
