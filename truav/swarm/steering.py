"""Steering a UAV of a running swarm from outside: the one place an override is checked and sent.

`truav-swarm steer`, the MAVLink bridge's repositions and the ROS 2 bridge's goals all come here: a goal is
a point of the run's area (x east, y north, metres), sent as :class:`truav.wire.schema.Override` on
control/override/<i> by a Bus of the ``operator`` identity (under --secure its credentials); the world flies
the UAV there (world/steer.py) and announces it on fault/override.
"""

from __future__ import annotations

import math
from typing import Any, Optional

from truav.wire import keys, schema


def inside_area(xy: tuple[float, float], area_m: float) -> bool:
    """A goal the world can fly to: two finite numbers in [0, area_m]."""
    return all(math.isfinite(v) and 0.0 <= v <= area_m for v in xy)


def send_override(bus: Any, run: str, uav: int, goal: Optional[tuple[float, float]], speed: float = 0.0) -> str:
    """Put an override of ``uav`` on ``bus`` (an ``operator`` Bus of ``run``): fly to ``goal`` at ``speed`` m/s
    (0: full speed), or release it (``goal`` None: its agent flies it again). The key it was put on."""
    key = keys.control_override(run, uav)
    bus.publish(key, schema.Override(uav=uav, release=goal is None, goal=goal or (0.0, 0.0), speed=speed))
    return key
