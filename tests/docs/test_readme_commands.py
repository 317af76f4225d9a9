"""Every command of the README's bash blocks, then of its tutorials' and how-to guides' shell blocks (in the
order the README lists them), then of tests/support/readme_commands.EXTRA_PAGES, in the order a reader meets
them, all in ONE directory, as a reader after the quick start has it: a page whose run collides with an
earlier page's (the same --out) fails here as it fails for the reader.

Each command is classified below: RUN (run, with the tiny budget given appended; argparse lets the last
flag win; never an --out or --force the page does not write) or CHECKED (not run here, with the reason;
parsed by the real parser unless it is not one of ours; a CHECKED `truav-swarm up` is still checked not to
land in an earlier run's --out or --record). A README command in neither table fails the test until it is
classified; so does an entry no longer in the README. Running them all takes a few minutes of CPU, so it
happens in CI (.ci/run sets TRUAV_README_COMMANDS=1; also with CI set) and on request; the classification
runs always.

Durations the pages state ("about 55 s") are in STATED_HOW, with how each is checked: a command this test
runs at its full budget fails here when it takes more than twice its stated time; the others are tiny here,
so their stated times are measured apart, at full budget, by bench/bench_doc_times.py (which fails on the
same 2x), or extrapolated where a run takes hours (the page says so).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.readme_commands import commands, key, program, stated_times

REPO = Path(__file__).resolve().parents[2]
ENTRY = {"truav": "truav.cli", "truav-swarm": "truav.cli.swarm"}

SMALL_CITY = ["--set", "scenario.n_vehicles=40", "--set", "roads.warmup_steps=5"]
# --max-missed 1: how many of a 5-tick real-time run's actions a loaded CI host misses is not what this test
# checks (tests/swarm/test_cold_start.py bounds the first ticks of a cold start, scheme by scheme).
SWARM = ["--episodes", "1", "--steps", "5", *SMALL_CITY, "--no-plot", "--quiet", "--max-missed", "1"]
# Two agents where the command's point is not the swarm's size (a policy, plan or Q-table sized for the default
# five keeps the default): each agent process costs ~0.6 CPU-s to start, and this test starts about a hundred.
FEW = [*SWARM, "--agents", "2"]
TRAIN = ["--seeds", "2", "--episodes", "3", "--workers", "1", "--quiet"]
VELOCITY = ["--quick", "--seeds", "1", "--episodes", "2", "--eval-episodes", "1", "--workers", "1", "--quiet"]

RUN: dict[str, list[str]] = {
    "truav-swarm up": SWARM,
    "truav train": TRAIN,
    "truav-swarm up --agents 8 --episodes 5 --out runs/swarm-8": SWARM,
    "truav-swarm up --scheme truav --out runs/swarm-truav": FEW,
    "truav-swarm up --scheme truav --lockstep --out runs/swarm-lockstep": FEW,
    "truav-swarm up --scheme truav --qtable runs/train-15mps --greedy --out runs/swarm-greedy": SWARM,
    "truav-swarm up --record runs/swarm-rec.mcap --out runs/swarm-rec": FEW,
    "truav-swarm up --scheme patrol --out runs/swarm-patrol": FEW,
    "truav-swarm up --scheme central --out runs/swarm-central": SWARM,
    "truav train --scheme central --seeds 1 --episodes 300 --out runs/train-central": TRAIN,
    "truav-swarm up --scheme central --policy runs/train-central --out runs/swarm-central-trained": SWARM,
    "truav-swarm up -v --force": FEW,
    # 100 and 50 agents: the same options at 20 agents (2 processes of 10), a CI machine's share
    "truav-swarm up --scheme truav --agents 100 --agents-per-process 10 --share-beacons --out runs/swarm-100":
        [*SWARM, "--agents", "20"],
    "truav-swarm up --scheme truav --agents 100 --agents-per-process 20 --share-beacons --batch-beacons --lockstep "
    "--out runs/swarm-100-lockstep": [*SWARM, "--agents", "20", "--agents-per-process", "10"],
    "truav-swarm up --scheme truav --agents 50 --beacon-hz 1 --agents-per-process 10 --share-beacons --out runs/swarm-50":
        [*SWARM, "--agents", "20"],
    "truav-swarm up --scheme truav --beacon-cell 500 --out runs/swarm-cells": FEW,
    "truav-swarm up --scheme truav --lockstep --set federated.every=1 --out runs/swarm-fed": FEW,
    "truav-swarm up --secure --out runs/swarm-secure": FEW,
    "truav-swarm acl explain --identity uav/1": [],
    "truav-swarm certs --deployment deploy/three-hosts.toml --out creds": [],
    "truav train --speed 25 --seeds 4 --episodes 1000 --out runs/quick": TRAIN,
    "truav evaluate runs/train-15mps --against random hover": ["--episodes", "1", "--workers", "1", "--quiet"],
    "truav config show": [],
    "truav config show --set scenario.n_uavs=8 --set learner.episodes=200": [],
    "truav config show --set learner.episodes=200 '>' my-config.toml": [],
    "truav train --config my-config.toml --out runs/my-config": TRAIN,
    "truav traffic build": [],
    "truav train --mobility sumo --seeds 2 --episodes 500 --out runs/train-sumo": TRAIN,
    "truav-swarm up --scheme truav --lockstep --mobility sumo --out runs/swarm-sumo": FEW,
    "truav experiment velocity --quick --mobility sumo --out runs/velocity-sumo": VELOCITY,
    "truav experiment velocity": VELOCITY,
    "truav experiment velocity --episodes-for central=1000": [*VELOCITY, "--episodes-for", "central=2"],
    "truav experiment velocity --quick": VELOCITY,
    "truav experiment scale --episodes 1000": [*VELOCITY],
    "truav experiment velocity --schemes truav central patrol patrol_ctrl --episodes-for patrol_ctrl=100":
        [*VELOCITY, "--episodes-for", "patrol_ctrl=2"],
    "truav-swarm up --scheme truav --record runs/demo.mcap --out runs/swarm-record": SWARM,
    "truav log check runs/demo.mcap": [],
    "truav-swarm up --scheme truav --lockstep --record runs/lockstep.mcap --out runs/swarm-lockstep-rec": SWARM,
    "truav log resim runs/lockstep.mcap": [],
    "truav log resim runs/lockstep.mcap --from 150 --greedy": ["--from", "3"],  # the tiny run has 6 ticks
    "truav report runs/demo.mcap": [],
    "truav log report runs/demo.mcap --out runs/demo-report": [],
    "truav log info runs/demo.mcap": [],
    "truav log cut runs/demo.mcap runs/demo-ticks.mcap --from-tick 2 --to-tick 3": [],
    "truav log cut runs/demo.mcap runs/demo-a.mcap --to-tick 2": [],
    "truav log cut runs/demo.mcap runs/demo-b.mcap --from-tick 3": [],
    "truav log merge runs/demo-ab.mcap runs/demo-a.mcap runs/demo-b.mcap": [],
    "truav-swarm up --record runs/foxglove.mcap --foxglove --out runs/swarm-foxglove": [*SWARM, "--foxglove", "0"],
    "truav-swarm up --record runs/parts.mcap --split-size 1 --split-duration 60 --out runs/swarm-parts": FEW,
    "truav-swarm up --record runs/snap.mcap --snapshot 10:5 --out runs/swarm-snap": FEW,
    "truav-swarm up --fault-plan deploy/plans/crash-and-freeze.toml --out runs/swarm-faults": SWARM,
    "truav-swarm chaos --plan deploy/plans/partition-latency.toml": SWARM,
    "truav-swarm up --scheme central --fault-plan deploy/plans/controller-crash.toml "
    "--out runs/swarm-controller-crash": SWARM,
    "truav-swarm chaos --scheme central --plan deploy/plans/controller-links.toml --out runs/chaos-central": SWARM,
    # the soak at 15 s (its schedule drawn for that); the re-run of its plan a little longer (it fails, honestly,
    # when its run ends before the plan's heal). At 5 Hz: beside the suite's other swarms a 10 Hz soak's agents
    # missed 7 of the 130 UAV-ticks after the heal, above the checker's 2% for a busy host (the host, not a fault).
    "PYTHONPATH=examples truav train --agent cell_agent:CellAgent --seeds 2 --episodes 100 --out runs/cell-agent": TRAIN,
    "PYTHONPATH=examples truav evaluate runs/cell-agent --against patrol hover": ["--episodes", "1", "--workers", "1", "--quiet"],
    "PYTHONPATH=examples truav-swarm up --agent cell_agent:CellAgent --qtable runs/cell-agent --greedy "
    "--out runs/swarm-cell-agent": SWARM,
    "PYTHONPATH=examples truav-swarm up --agent cell_agent:CellAgent --qtable runs/cell-agent --greedy "
    "--fault-plan deploy/plans/crash-and-freeze.toml --max-missed 0.2 --out runs/swarm-cell-agent-faults": SWARM,
    "PYTHONPATH=examples truav-swarm up --lockstep --agent cell_agent:CellAgent --qtable runs/cell-agent --greedy "
    "--episodes 1 --record runs/cell-agent.mcap --out runs/swarm-cell-agent-rec": SWARM,
    "PYTHONPATH=examples truav log resim runs/cell-agent.mcap --agent cell_agent:CellAgent": [],
    "truav config show --preset paper --set learner.sense_range_m=1500 '>' paper-1500.toml": [],
    "truav-swarm up --lockstep --episodes 2 --record runs/ros2-demo.mcap --out runs/swarm-ros2": FEW,
    "truav log ros2bag runs/ros2-demo.mcap --out runs/ros2-demo_bag": [],
    "truav-swarm chaos --nemesis random --duration 10m --seed 1 --out runs/chaos-soak":
        ["--duration", "15s", "--rate", "5", "--steps", "50", *SMALL_CITY, "--no-plot", "--quiet"],
    "truav-swarm chaos --plan runs/chaos-soak/nemesis-plan.toml --out runs/chaos-soak-again":
        ["--episodes", "2", "--steps", "40", "--rate", "5", *SMALL_CITY, "--no-plot", "--quiet"],
}
"""Run in order, each with these flags appended; each must exit 0."""

SETUP = "the environment the check runs in was set up so (the quick start's install)"
OTHER_TERMINAL = "needs a swarm running in another terminal; the parts it talks to are tested in tests/swarm/test_swarm*.py"
OTHER_HOST = "a part for another host (ROUTER, ~/truav-creds are the user's); tests/swarm/test_multihost.py runs them"
LONG = "an experiment of minutes (many swarm runs); its code runs small in tests/swarm/test_fault_sweep.py, test_scheme_faults.py"
REPLAY_RUNNING = "needs a replay running in another terminal; tests/swarm/test_replay_ctl.py runs replay-ctl against one"
BENCH = "a benchmark: minutes, and it measures the host (bench/ is run by hand)"
OWN_CLASS = ("needs the page's agent class in ~/mylab (the reader's own file); tests/swarm/test_agent_api.py and "
             "test_agent_api_swarm.py train, evaluate and fly the same class")
OUTSIDE = ("waits for an outside agent (examples/outside_agent.py) in a second terminal; "
           "tests/swarm/test_outside_agent.py flies one beside such a swarm")
CHECKED: dict[str, str] = {
    "python3 -m venv .venv": SETUP,
    ". .venv/bin/activate": SETUP,
    "pip install -e . -c constraints.txt": SETUP,
    "pip install -e '.[dev]' -c constraints.txt": SETUP,
    "pip install -e '.[central]' -c constraints.txt": SETUP + " ([dev] includes PyTorch)",
    "pip install -e '.[mavlink]' -c constraints.txt": SETUP + " ([dev] includes pymavlink)",
    "truav-swarm up --run gcs --episodes 20": "the background run the ground-control how-to's bridge serves; "
                                              "tests/swarm/test_mavlink_bridge.py runs a swarm with the bridge",
    "truav-swarm mavlink --run gcs": "runs until the run ends, for a ground station in another window; "
                                     "tests/swarm/test_mavlink_bridge.py runs it against a pymavlink listener",
    "python -m pytest -q -n 3": "the test suite this test is part of",
    "truav-swarm status": OTHER_TERMINAL,
    "truav-swarm down --run demo": OTHER_TERMINAL,
    "truav-swarm router -l tcp/0.0.0.0:7447": "listens on every interface until stopped (a router for other hosts); "
                                             "routers on loopback run in every swarm test",
    "truav-swarm world --run demo -e tcp/ROUTER:7447 --episodes 3": OTHER_HOST,
    "truav-swarm agent --id 0 --run demo -e tcp/ROUTER:7447 --checkpoint agent0.npz": OTHER_HOST,
    "truav-swarm router --creds '~/truav-creds'": OTHER_HOST,
    "truav-swarm world --run demo --set scenario.n_uavs=4 --creds '~/truav-creds'": OTHER_HOST,
    "truav experiment velocity --executor ray": "starts a Ray instance (tens of seconds, about a GB); "
                                                "tests/swarm/test_ray_executor.py runs cells on one",
    "ray start --head --port 6379": "Ray's own command: starts a cluster head that outlives the test",
    "truav experiment velocity --executor ray --address HEAD:6379": "needs a Ray cluster at HEAD",
    "truav log recover broken.mcap fixed.mcap": "needs a recording whose recorder was killed (broken.mcap is the "
                                                "user's); tests/swarm/test_recorder_process.py kills one and recovers it",
    "truav-swarm replay runs/demo.mcap --rate 2 --topics 'truav/*/uav/1/obs' --paused":
        "starts paused, waiting for keys or bus commands; replay is tested in tests/swarm/test_replay.py",
    "truav-swarm record --run demo --out other.mcap -e tcp/127.0.0.1:7447": OTHER_TERMINAL,
    "truav-swarm replay-ctl --run demo -e tcp/127.0.0.1:7447 seek --tick 40": REPLAY_RUNNING,
    "truav-swarm replay-ctl --run demo -e tcp/127.0.0.1:7447 seek --by -5": REPLAY_RUNNING,
    "truav-swarm replay-ctl --run demo -e tcp/127.0.0.1:7447 rate 4": REPLAY_RUNNING,
    "truav log play runs/parts.parts.json --rate 4 --paused":
        "starts paused, waiting for keys or bus commands; tests/unit/test_replay_seek.py plays parts as one",
    "truav log play-ctl --run demo -e tcp/127.0.0.1:7447 status": REPLAY_RUNNING,
    "truav-swarm replay runs/demo.mcap --lockstep --topics 'truav/*/world/tick' 'truav/*/uav/1/obs' "
    "-e tcp/127.0.0.1:7447": "needs a live agent answering in another terminal; tests/swarm/test_replay_ctl.py runs one",
    "truav log play runs/demo.mcap --rate 2 --paused":
        "starts paused, waiting for keys or bus commands; the same command as truav-swarm replay (tests/swarm/test_log_group.py)",
    "truav log record --run demo --out other.mcap -e tcp/127.0.0.1:7447": OTHER_TERMINAL,
    "truav log record-ctl pause --run demo -e tcp/127.0.0.1:7447":
        OTHER_TERMINAL + " (tests/swarm/test_record_modes.py sends it to a recorder)",
    "truav-swarm view -e tcp/127.0.0.1:7447 --run demo": OTHER_TERMINAL,
    "truav-swarm replay runs/demo.mcap -e tcp/127.0.0.1:7447": OTHER_TERMINAL,
    "truav-swarm faults --run demo --plan my.toml -e tcp/127.0.0.1:7447": OTHER_TERMINAL + " (my.toml: the user's plan)",
    "truav experiment faults --quick --schemes truav central patrol --rate 5 --out runs/faults-schemes": LONG,
    "truav experiment faults --quick --schemes federated truav_online --rate 5 --out runs/faults-federated": LONG,
    "truav experiment faults --qtable runs/train-15mps": LONG,
    "truav experiment faults --quick": LONG,
    "pip install -e '.[ros2]' -c constraints.txt": SETUP + " ([dev] includes rosbags)",
    "pip install -e '.[marl]' -c constraints.txt": SETUP + " ([dev] includes Stable-Baselines3 and PyTorch)",
    "python examples/train_sb3.py --steps 200000": "trains for minutes; tests/docs/test_train_sb3_howto.py runs "
                                                   "the file with a tiny budget, then flies what it wrote",
    "PYTHONPATH=examples truav-swarm up --agent train_sb3:Sb3Agent --scenario paper-1500.toml --out runs/swarm-sb3":
        "flies the weights the training above writes (not run here); tests/docs/test_train_sb3_howto.py "
        "flies a tiny training's weights",
    **{c: "ROS 2's own tools (not installed here); tests/unit/test_ros2bag.py and tests/swarm/test_ros2bag_swarm.py "
          "read the bags with rosbags and mcap-ros2-support" for c in (
        "ros2 bag info runs/ros2-demo_bag", "ros2 bag play runs/ros2-demo_bag", "rviz2")},
    "truav-swarm up --run ros2live --episodes 20": "the background run the ROS 2 how-to's bridge serves; "
                                                   "tests/swarm/test_ros2_bridge.py runs a swarm with the bridge",
    "truav-swarm ros2 --run ros2live": "runs until the run ends, for ROS 2 on another terminal; "
                                       "tests/swarm/test_ros2_bridge.py runs it against zenoh-ros2-sdk",
    **{c: "the ROS 2 machine's (rmw_zenoh_cpp and ros2 are not installed here); tests/swarm/test_ros2_bridge.py "
          "lists, echoes and finds the node with zenoh-ros2-sdk, an independent rmw_zenoh client" for c in (
        "export RMW_IMPLEMENTATION=rmw_zenoh_cpp", "export 'ZENOH_CONFIG_OVERRIDE=connect/endpoints=[\"tcp/SWARM_HOST:PORT\"]'",
        "ros2 run rmw_zenoh_cpp rmw_zenohd", "ros2 topic list -t", "ros2 node list",
        "ros2 topic echo /truav/uav_0/pose")},
    "ros2 topic pub --once /truav/uav_1/goal geometry_msgs/msg/PoseStamped '{header: {frame_id: map}, pose: "
    "{position: {x: 2500.0, y: 2500.0}}}'": "the ROS 2 machine's; tests/swarm/test_ros2_bridge.py publishes a goal "
                                            "with zenoh-ros2-sdk, an independent rmw_zenoh client",
    "truav-swarm up --run steer --agents 5 --episodes 2": "the background run the steering how-to steers; "
                                                         "tests/swarm/test_steer_swarm.py steers a swarm",
    **{c: "needs the how-to's background run; tests/swarm/test_steer_swarm.py runs steer, its release and its "
          "mistakes against a swarm" for c in (
        "truav-swarm steer --run steer 3 --to 2500,1200", "truav-swarm steer --run steer 3 --to 400,400 --speed 7",
        "truav-swarm steer --run steer 3 --release")},
    **{c: "needs a --secure run's credentials; tests/swarm/test_steer_security.py checks the operator's rights "
          "at the router" for c in (
        "truav-swarm steer --run steer --creds creds 3 --to 2500,1200",
        "truav-swarm acl explain --creds creds --identity operator")},
    "truav-swarm router -l tcp/127.0.0.1:7460": "a router of the reader's own, for the replay and its control "
                                                "below; routers on loopback run in every swarm test",
    "truav-swarm replay runs/demo.mcap -e tcp/127.0.0.1:7460 --paused":
        "starts paused, waiting for keys or bus commands; replay is tested in tests/swarm/test_replay.py",
    "truav-swarm replay-ctl --run demo -e tcp/127.0.0.1:7460 status": REPLAY_RUNNING,
    "pip install 'eclipse-zenoh>=1.0' 'msgpack>=1.0'": SETUP + " (both are TRUAV's own dependencies)",
    "truav-swarm up --scheme truav --agents 3 --lockstep --episodes 1 --steps 20 --external 2 --out runs/swarm-external": OUTSIDE,
    "'PYTHONPATH=~/mylab' truav train --agent bandit_agent:Bandit --seeds 4 --episodes 200 --out runs/bandit":
        OWN_CLASS,
    "'PYTHONPATH=~/mylab' truav evaluate runs/bandit --against patrol hover": OWN_CLASS,
    "'PYTHONPATH=~/mylab' truav experiment velocity --quick --schemes bandit_agent:Bandit truav patrol --speeds 15 "
    "--out runs/bandit-velocity": OWN_CLASS,
    "'PYTHONPATH=~/mylab' truav experiment faults --quick --schemes bandit_agent:Bandit truav patrol "
    "--out runs/bandit-faults": OWN_CLASS,
    "'PYTHONPATH=~/mylab' truav-swarm up --lockstep --agent bandit_agent:Bandit --episodes 4 --out runs/bandit-swarm":
        OWN_CLASS,
    "'PYTHONPATH=~/mylab' truav-swarm up --agent bandit_agent:Bandit --fault-plan deploy/plans/crash-and-freeze.toml "
    "--out runs/bandit-faulted": OWN_CLASS,
    "'PYTHONPATH=~/mylab' truav-swarm up --agent bandit_agent:Bandit --qtable runs/bandit --greedy "
    "--out runs/bandit-greedy": OWN_CLASS,
    **{c: BENCH for c in (
        "python bench/bench_trainer.py", "python bench/bench_trainer.py --full",
        "python bench/bench_trainer.py --agent truav", "python bench/bench_ppo_training.py",
        "python bench/bench_ppo_training.py --full", "python bench/bench_sumo.py",
        "python bench/bench_policy_realtime.py --schemes truav,ppo,ppo-claim", "python bench/bench_policy_memory.py",
        "python bench/bench_ray_swarm.py --rate 2",
        "python bench/bench_sac.py '[--compare' 'DIR]' '[--config' 'literal]'", "python bench/bench_recorder.py",
        "python bench/bench_recorder_bus.py", "python bench/bench_swarm.py --repeat 5", "python bench/bench_schema.py",
        "python bench/bench_inbox.py", "python bench/bench_beacon_burst.py",
        "python bench/bench_swarm.py --secure", "python bench/bench_flood.py",
        "python bench/bench_swarm.py --sweep 5,10,20,50,100 --variants base,hz1,cells,k10+shared",
        "python bench/bench_swarm.py --sweep 20,50 --modes realtime --compare ../old --max-load 1")},
}
"""Not run here, and why."""

TIMEOUT_S = 240

MEASURED_APART = "measured apart at full budget by bench/bench_doc_times.py (here it runs tiny)"
STATED_HOW: dict[str, str] = {
    "truav-swarm up": MEASURED_APART,
    "truav train": MEASURED_APART,
    "truav experiment velocity": "over an hour: extrapolated from the measured rates of its parts (the page says how)",
    "truav experiment faults --qtable runs/train-15mps": MEASURED_APART,
    "truav experiment faults --quick": MEASURED_APART,
    "truav experiment faults --quick --schemes truav central patrol --rate 5 --out runs/faults-schemes": MEASURED_APART,
    **{c: MEASURED_APART for c in (
        "PYTHONPATH=examples truav train --agent cell_agent:CellAgent --seeds 2 --episodes 100 --out runs/cell-agent",
        "PYTHONPATH=examples truav evaluate runs/cell-agent --against patrol hover",
        "PYTHONPATH=examples truav-swarm up --agent cell_agent:CellAgent --qtable runs/cell-agent --greedy "
        "--out runs/swarm-cell-agent",
        "PYTHONPATH=examples truav-swarm up --agent cell_agent:CellAgent --qtable runs/cell-agent --greedy "
        "--fault-plan deploy/plans/crash-and-freeze.toml --max-missed 0.2 --out runs/swarm-cell-agent-faults",
        "PYTHONPATH=examples truav-swarm up --lockstep --agent cell_agent:CellAgent --qtable runs/cell-agent --greedy "
        "--episodes 1 --record runs/cell-agent.mcap --out runs/swarm-cell-agent-rec",
        "PYTHONPATH=examples truav log resim runs/cell-agent.mcap --agent cell_agent:CellAgent")},
}
"""Every duration a page states, and how it is checked."""


def _swarm_outputs(argv: list[str]) -> tuple[list[Path], bool] | None:
    """(--out directory and --record file, whether it may replace them) of a `truav-swarm up` command."""
    from truav.cli.swarm import build_parser
    from truav.swarm.swarm_options import default_out_dir
    argv = program(argv)
    if argv[:2] != ["truav-swarm", "up"]:
        return None
    args = build_parser().parse_args(argv[1:])
    paths = [Path(args.out) if args.out else default_out_dir(args.run)]
    if args.record:
        paths.append(Path(args.record))
    return paths, bool(args.force or args.resume)


def _parse(argv: list[str]) -> None:
    """Our own commands go through their real parser (a renamed or misspelt flag fails here)."""
    from truav.cli.main import build_parser as truav_parser
    from truav.cli.swarm import build_parser as swarm_parser
    argv = program(argv)
    parser = {"truav": truav_parser, "truav-swarm": swarm_parser}[argv[0]]()
    parser.parse_args(argv[1:argv.index(">")] if ">" in argv else argv[1:])


def test_every_readme_command_is_classified_and_parses() -> None:
    found = [key(c) for c in commands()]
    unknown = [c for c in found if c not in RUN and c not in CHECKED]
    assert not unknown, f"README commands neither run nor checked (add each to RUN or CHECKED): {unknown}"
    stale = [c for c in [*RUN, *CHECKED] if c not in found]
    assert not stale, f"no longer in the README: {stale}"
    for argv in commands():
        if program(argv)[0] in ENTRY:
            _parse(argv + RUN.get(key(argv), []))


def test_no_command_lands_in_an_earlier_commands_run() -> None:
    """Read in order, no `truav-swarm up` (run here or not) writes an --out or --record an earlier one wrote,
    unless it says --force or --resume: the reader's second run would refuse to start."""
    written: dict[Path, str] = {}
    clashes = []
    for argv in commands():
        found = _swarm_outputs(argv)
        if found is None:
            continue
        paths, replaces = found
        clashes += [f"`{key(argv)}` writes {p}, as `{written[p]}` did before it" for p in paths
                    if p in written and not replaces]
        written.update({p: key(argv) for p in paths})
    assert not clashes, "give each its own --out (or --record):\n" + "\n".join(clashes)


def test_every_stated_duration_says_how_it_is_checked() -> None:
    stated = stated_times()
    assert sorted(set(stated) - set(STATED_HOW)) == [], "a page states a duration: say in STATED_HOW how it is checked"
    assert sorted(set(STATED_HOW) - set(stated)) == [], "STATED_HOW names a command whose page states no duration"
    full_here = [c for c, how in STATED_HOW.items() if how.startswith("run at its full budget")]
    assert [c for c in full_here if RUN.get(c) != []] == [], "a duration checked here needs the command run as written"


def _run(argv: list[str], cwd: Path, env: dict) -> tuple[int, str]:
    assigned = argv[:len(argv) - len(program(argv))]  # the reader's VAR=value before the command
    env = {**env, **{k: os.path.expanduser(v) + (os.pathsep + env[k] if k == "PYTHONPATH" and env.get(k) else "")
                     for k, v in (a.split("=", 1) for a in assigned)}}
    argv = program(argv)
    out_file = None
    if ">" in argv:  # the README's one redirection
        at = argv.index(">")
        argv, out_file = argv[:at], cwd / argv[at + 1]
    full = [sys.executable, "-m", ENTRY[argv[0]], *argv[1:]]
    with open(out_file or os.devnull, "w") as stdout:
        proc = subprocess.Popen(full, cwd=cwd, env=env, stdin=subprocess.DEVNULL, start_new_session=True,
                                stdout=stdout if out_file else subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            text, _ = proc.communicate(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # its own session: the swarm it started with it
            text, _ = proc.communicate()
            text = (text or "") + f"\n(killed after {TIMEOUT_S} s)"
    return proc.returncode, text or ""


@pytest.mark.skipif(not (os.environ.get("TRUAV_README_COMMANDS") or os.environ.get("CI")),
                    reason="runs every README command (minutes): set TRUAV_README_COMMANDS=1 (CI does)")
@pytest.mark.timeout(1800)  # ~55 commands in turn, minutes: beyond the suite's 300 s; each is bounded by TIMEOUT_S
def test_readme_commands_run_in_order_in_a_fresh_directory(tmp_path: Path) -> None:
    """A fresh clone after the quick start: the repository's files, no runs/ yet; every page's commands in
    this one directory, in the reader's order."""
    from truav.swarm.outdir import OutDirError, check_swarm_dir
    work = tmp_path / "clone"
    work.mkdir()
    for folder in ("deploy", "examples"):  # the plans, deployments and agent classes the commands name
        shutil.copytree(REPO / folder, work / folder)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    stated = stated_times()
    for argv in commands():
        name = key(argv)
        if name in CHECKED:
            found = _swarm_outputs(argv)
            if found:  # not run here; the reader's run would still start only in a free --out
                try:
                    check_swarm_dir(work / found[0][0], resume=False, force=found[1])
                except OutDirError as e:
                    pytest.fail(f"`{name}` (not run here) would refuse to start: {e}")
            continue
        began = time.monotonic()
        rc, text = _run(argv + RUN[name], work, env)
        took = time.monotonic() - began
        print(f"{took:6.1f} s  {name}", flush=True)  # the check's cost, command by command
        assert rc == 0, f"`{name}` (+ {' '.join(RUN[name])}) exited {rc}:\n{text[-3000:]}"
        if STATED_HOW.get(name, "").startswith("run at its full budget"):
            assert took <= 2 * stated[name], f"`{name}` took {took:.0f} s, more than twice the {stated[name]:.0f} s its page states"
