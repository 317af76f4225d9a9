"""The golden run: digests of run_chunk(kind, SMALL, [0, 7], 3) recorded before channel models and link
models existed; the default channel and links must change no number (tests/unit/test_channel_models.py,
tests/unit/test_link_phy.py)."""

from __future__ import annotations

import hashlib

import numpy as np

GOLDEN = {
    # sha256 of the metrics (sorted keys, float64) and of the Q-tables of run_chunk(kind, SMALL, [0, 7], 3),
    # recorded on commit ab721b6, before channel models existed: the default channel changes no number.
    "truav": ("7ba9b5abcfc2c31b326b987d86edde60f66ccf570fdd69862cc78051a8879671",
              "ed248b234cbc01c242e7195a70c076e18b8faf5493068c796f5a873e69a46db6"),
    "patrol": ("4d5f7631094a627d14e28d0c5e1e2a832f14a48c29a9f8e897ab89ad1297254a", None),
}
SMALL = {"scenario": {"n_vehicles": 60, "steps_per_episode": 20}, "roads": {"warmup_steps": 20},
         "learner": {"episodes": 3}}


def digest(result) -> tuple[str, str | None]:
    """sha256 of a run_chunk result's metrics (sorted keys, float64) and of its Q-tables."""
    h = hashlib.sha256()
    for k in sorted(result.metrics):
        h.update(k.encode())
        h.update(np.ascontiguousarray(result.metrics[k], dtype=np.float64).tobytes())
    q = None if result.q is None else hashlib.sha256(np.ascontiguousarray(result.q).tobytes()).hexdigest()
    return h.hexdigest(), q
