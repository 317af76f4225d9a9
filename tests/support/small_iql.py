"""The deep learner (agents.deep_iql) with tiny buffers and early, frequent updates: a few 10-step episodes
exercise replay wrap-around, Adam and target copies (the defaults would not update before episode 10 of 100
steps). Self-contained (agents.deep_iql only), so a swarm test can hand its source to agent processes."""

from dataclasses import replace

from agents import deep_iql

SMALL = replace(deep_iql.DeepIqlConfig(), replay_capacity=24, warmup=6, train_every=2, target_every=3, batch_size=5)


class SmallBatched(deep_iql.DeepIqlBatched):
    hp = SMALL


class Small(deep_iql.DeepIql):
    hp = SMALL
    batched = SmallBatched
