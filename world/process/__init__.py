"""The world as a process on the bus: WorldNode (world_process) and its host (world_host: session, stop, final stats)."""
