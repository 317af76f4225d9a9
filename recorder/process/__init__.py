"""The recorder and the replay as processes on the bus: the recording node (recorder) and the replay's bus side (replay_bus)."""
