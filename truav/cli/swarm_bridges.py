"""What `truav-swarm mavlink` and `truav-swarm ros2` share: the run found and its scenario read, the
``operator`` identity's config that steering goes out as, and one line of what the bridge did however it ended."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from truav.cli.run_lookup import find_run
from truav.cli.swarm_common import config_from_args, operator_config, part_creds, setup_logging

if TYPE_CHECKING:
    from truav.config import Config


@dataclass(frozen=True)
class BridgeRun:
    scenario: Path  # the run's scenario file; missing: the default scenario's geometry
    cfg: Config
    steer_config: Any  # the operator's zenoh config (under --secure its credentials)

    def geometry_note(self) -> str:
        """What the ready line adds when the run has no scenario file."""
        return "" if self.scenario.is_file() else f" (no {self.scenario}: the default scenario's geometry)"


def open_bridge_run(args) -> BridgeRun:
    """The run of ``args`` (--run, --out), its scenario (a bad file: ConfigError, one line naming it), the
    operator's config, the view's credentials checked, logging set up."""
    from truav.config import load_config
    from truav.swarm.outdir import SCENARIO_FILE

    scenario = Path(find_run(args)) / SCENARIO_FILE
    cfg = load_config(scenario if scenario.is_file() else None)
    steer_config = operator_config(args)
    part_creds(args, "view")
    setup_logging(args.verbose)
    return BridgeRun(scenario, cfg, steer_config)


def serve_bridge(command: str, args, run: BridgeRun, run_bridge: Callable[..., Any], bridge: Any, stop: Any,
                 ready_line: Callable[[], str], summary: Callable[[], str]) -> int:
    """``run_bridge`` (truav/swarm/<bridge>.run_bridge) until the run shuts down or ``stop`` is set:
    ``ready_line()`` on stdout once it serves, and however it ends (Ctrl-C and SIGTERM too, exit 130 / 143)
    one line on stderr of what was done, ``summary()`` and the bus messages that did not fit their kind."""
    def ready() -> None:
        print(ready_line() + run.geometry_note(), flush=True)

    why = "stopped"
    try:
        run_bridge(args.run, config_from_args(args), bridge, stop=stop, ready=ready, steer_config=run.steer_config)
        why = "the run shut down"
    finally:
        odd = bridge.stats.odd
        print(f"truav-swarm {command}: {why}: {summary()}"
              + (f", {odd} bus message(s) that did not fit their kind" if odd else ""), file=sys.stderr)
    return 0
