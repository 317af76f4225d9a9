"""Every user mistake is one line on stderr naming the flag or file, a non-zero exit code
(2 for a usage error), no traceback, and nothing started.

Each row is a command line of `truav` or `truav-swarm` with the bad files it needs; most run
in-process through ``main(argv)`` with the starters of work (trainer, swarm supervisor, chaos,
fault sweep, recorder, Zenoh sessions, subprocesses) replaced by a trap that fails the test, so
a row passes only if the mistake is caught before anything starts.  A few rows run the real
entry points as subprocesses.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from recorder.mcap_log import McapLog
from recorder.metadata import (CONFIG_METADATA, RECORDING_METADATA, RUN_METADATA, config_metadata,
                               run_info_metadata)
from recorder.record_modes import PART_METADATA
from truav.cli.main import main as truav_main
from truav.config import Config, to_toml
from truav.cli.swarm import main as swarm_main

GOOD_PLAN = '[[fault]]\nkind = "crash"\nstart = 1.0\nuav = 1\n'


def _recording(path: Path) -> bytes:
    """A small finished recording of beacons from 3 UAVs in many chunks (so some can be corrupted)."""
    import msgpack
    with McapLog(path, chunk_bytes=2048, mirrors=False) as log:
        for i in range(600):
            u = i % 3
            payload = msgpack.packb({"v": 1, "kind": "beacon", "src": f"uav/{u}", "seq": i // 3, "t": 10**18 + i})
            log.write(f"truav/r/uav/{u}/beacon", payload, 10**18 + i * 10**6)
    return path.read_bytes()


def _lockstep_recording(path: Path, extra: dict[str, dict[str, str]]) -> None:
    """A recording of a lock-step run as `truav-swarm up --lockstep --record` makes it, holding only health
    messages (no tick), with the metadata records of ``extra`` too."""
    import msgpack
    with McapLog(path, mirrors=False) as log:
        log.set_metadata(RECORDING_METADATA, {"run": "r"})
        log.set_metadata(CONFIG_METADATA, config_metadata(to_toml(Config())))
        log.set_metadata(RUN_METADATA, run_info_metadata({"seed": 0, "lockstep": True, "episodes": 1}))
        for name, record in extra.items():
            log.set_metadata(name, record)
        log.write("truav/r/uav/0/health", msgpack.packb({"v": 1, "kind": "health", "src": "uav/0", "seq": 0,
                                                        "t": 10**18}), 10**18)


def _dead_pid() -> int:
    """The PID of a process that has ended (reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("bad")
    rng = np.random.default_rng(13)
    (d / "random.toml").write_bytes(rng.integers(0, 256, 300, dtype=np.uint8).tobytes())
    (d / "a_file").write_text("a regular file, not a directory\n")
    (d / "uav99.toml").write_text('[[fault]]\nkind = "crash"\nstart = 1.0\nuav = 99\n')
    (d / "badglob.toml").write_text('[[fault]]\nkind = "loss"\nprobability = 0.5\nkeys = "uav/[*/beacon"\n')
    (d / "typoglob.toml").write_text('[[fault]]\nkind = "loss"\nprobability = 0.5\nkeys = "uavs/*/beacon"\n')
    (d / "plan.toml").write_text(GOOD_PLAN)
    (d / "ctrl.toml").write_text('[[fault]]\nkind = "crash"\nstart = 1.0\ntarget = "controller"\n')
    (d / "empty.npz").write_bytes(b"")
    (d / "unclosed.json5").write_text('{"mode": "client"')
    (d / "bad_run_dir").mkdir()
    (d / "earlier_run").mkdir()  # what a swarm run that ticked leaves
    (d / "earlier_run" / "world.json").write_text('{"ticks": 200}')
    (d / "earlier_run" / "agent0.npz").write_bytes(b"")
    (d / "earlier_run" / "truav-run.json").write_text("{}")  # and its marker (truav.swarm.outdir)
    (d / "bad_run_dir" / "swarm.json").write_text('{"endpoint": "garbage"}')
    cfg = to_toml(Config())
    for name in ("run_empty", "run_trunc", "run_foreign", "run_shape"):
        (d / name).mkdir()
        (d / name / "config.toml").write_text(cfg)
    (d / "run_empty" / "qtables.npz").write_bytes(b"")
    np.savez(d / "run_foreign" / "qtables.npz", weights=np.zeros(3))
    np.savez_compressed(d / "run_shape" / "qtables.npz", q=np.zeros((1, 5, 10, 16), np.float32), seeds=np.array([0]))
    whole = (d / "run_shape" / "qtables.npz").read_bytes()
    (d / "run_trunc" / "qtables.npz").write_bytes(whole[: len(whole) // 2])
    data = _recording(d / "good.mcap")
    corrupt = bytearray(data)
    for i in range(len(data) // 3, len(data) // 3 + 2000):  # garble the middle chunks, keep the footer
        corrupt[i] ^= 0x5A
    (d / "corrupt.mcap").write_bytes(bytes(corrupt))
    (d / "unfinished.mcap").write_bytes(data[: len(data) * 2 // 3])  # the recorder "died" two thirds in
    (d / "header_only.mcap").write_bytes(data[:40])
    _lockstep_recording(d / "no_ticks.mcap", {})  # a lock-step run's recording that ended before tick 0
    _lockstep_recording(d / "run_0002.mcap", {PART_METADATA: {"session": "s", "part": "2", "reason": "end"}})
    (d / "run.parts.json").write_text(json.dumps({"version": 1, "parts": [{"part": 1, "path": "run_0002.mcap"}]}))
    for name, info in (("ended_run", {"supervisor_pid": os.getpid()}), ("dead_run", {"supervisor_pid": _dead_pid()}),
                       ("tls_run", {"supervisor_pid": os.getpid(), "endpoint": "tls/127.0.0.1:7447"})):
        (d / name).mkdir()
        (d / name / "swarm.json").write_text(json.dumps({"run": name, "endpoint": "tcp/127.0.0.1:7447", **info}))
    (d / "ended_run" / "summary.json").write_text("{}")
    names = {p.name.replace(".", "_"): str(p) for p in d.iterdir()}
    names["dir"] = str(d)
    return names


class Started(AssertionError):
    """Something began work although the command line was wrong."""


@pytest.fixture
def nothing_starts(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # default output directories (runs/...) land here, not in the repository
    def trap(*_a, **_k):
        raise Started("work started before the mistake was caught")
    import truav.cli.log_process
    import recorder.process.replay_bus
    import truav.swarm.fault_sweep
    import truav.experiments.runner
    import truav.swarm.chaos
    import agents.process.agent_host
    import agents.process.controller_host
    import truav.cli.swarm_ops
    import truav.bus.router
    import world.process.world_host
    import truav.swarm.supervisor
    import truav.analysis.trainer
    import truav.analysis.sumo_traffic
    for module, name in ((truav.analysis.trainer, "run_parallel"), (truav.analysis.sumo_traffic, "checked_trace"), (truav.experiments.runner, "run_cells"),
                         (truav.swarm.supervisor, "run_swarm"), (truav.swarm.chaos, "run_chaos"),
                         (truav.swarm.fault_sweep, "run_sweep"), (world.process.world_host, "Bus"),
                         (agents.process.agent_host, "Bus"), (agents.process.controller_host, "Bus"), (truav.cli.swarm_ops, "Bus"),
                         (truav.bus.router, "run_router"), (truav.cli.log_process, "cmd_record"),
                         (recorder.process.replay_bus, "replay_on_bus"),
                         (subprocess, "Popen")):
        monkeypatch.setattr(module, name, trap)


DEPLOYMENT = Path(__file__).resolve().parents[2] / "deploy" / "three-hosts.toml"

# (id, main, argv, exit code, what stderr must name). {x} is a file of the `files` fixture.
ROWS = [
    # truav train / config / evaluate
    ("train-seed-start", "truav", "train --seed-start -1", 2, "--seed-start"),
    ("train-seeds-0", "truav", "train --seeds 0", 2, "--seeds"),
    ("train-workers-0", "truav", "train --workers 0", 2, "--workers"),
    ("train-speed-nan", "truav", "train --speed nan", 2, "--speed"),
    ("train-out-under-file", "truav", "train --out {a_file}/run", 2, "--out"),
    # federated.every with a scheme or agents that share nothing (was accepted; the summary said federated)
    ("train-central-federated", "truav", "train --scheme central --set federated.every=1", 2, "federated.every"),
    ("up-patrol-federated", "truav-swarm", "up --scheme patrol --set federated.every=2", 2, "federated.every"),
    ("up-greedy-federated", "truav-swarm", "up --greedy --set federated.every=1", 2, "federated.every"),
    ("train-out-is-file", "truav", "train --out {a_file}", 2, "--out"),
    ("train-out-empty", "truav", ["train", "--out", ""], 2, "--out: empty path"),
    ("train-speed-contradicts-set", "truav", "train --speed 20 --set scenario.uav_speed_mps=10", 2, "--set"),
    ("train-config-random-bytes", "truav", "train --config {random_toml}", 2, "random.toml"),
    ("train-config-directory", "truav", "train --config {dir}", 2, "not a regular file"),
    ("config-show-random-bytes", "truav", "config show --config {random_toml}", 2, "random.toml"),
    ("evaluate-episodes-0", "truav", "evaluate {run_shape} --episodes 0", 2, "--episodes"),
    ("evaluate-empty-npz", "truav", "evaluate {run_empty}", 2, "qtables.npz"),
    ("evaluate-truncated-npz", "truav", "evaluate {run_trunc}", 2, "qtables.npz"),
    ("evaluate-foreign-npz", "truav", "evaluate {run_foreign}", 2, "qtables.npz"),
    ("evaluate-wrong-shape", "truav", "evaluate {run_shape}", 2, "states"),
    ("evaluate-no-such-run", "truav", "evaluate {dir}/doesnotexist", 2, "doesnotexist: no such run"),
    # truav experiment
    ("velocity-episodes-0", "truav", "experiment velocity --quick --episodes 0", 2, "--episodes"),
    ("velocity-window-0", "truav", "experiment velocity --quick --window 0", 2, "--window"),
    ("velocity-seeds-per-cell-0", "truav", "experiment velocity --quick --seeds-per-cell 0", 2, "--seeds-per-cell"),
    ("velocity-out-is-file", "truav", "experiment velocity --quick --out {a_file}", 2, "--out"),
    ("velocity-config-random", "truav", "experiment velocity --quick --config {random_toml}", 2, "random.toml"),
    ("scale-uavs-0", "truav", "experiment scale --quick --uavs 0", 2, "--uavs"),
    ("faults-rate-0", "truav", "experiment faults --quick --rate 0", 2, "--rate"),
    ("faults-rate-nan", "truav", "experiment faults --quick --rate nan", 2, "--rate"),
    ("faults-seed-negative", "truav", "experiment faults --quick --seed -1", 2, "--seed"),
    ("faults-out-is-file", "truav", "experiment faults --quick --out {a_file}", 2, "--out"),
    ("faults-qtable-empty", "truav", "experiment faults --quick --qtable {run_empty}", 2, "--qtable"),
    # truav report / log
    ("report-corrupt-mcap", "truav", "report {corrupt_mcap} --out {dir}/rep", 1, "corrupt.mcap"),
    ("report-out-under-file", "truav", "report {good_mcap} --out {a_file}/rep", 2, "--out"),
    ("check-unfinished", "truav", "log check {unfinished_mcap}", 1, "truav log recover"),
    ("check-corrupt", "truav", "log check {corrupt_mcap}", 1, "corrupt.mcap"),
    ("check-max-ranges", "truav", "log check {good_mcap} --max-ranges -1", 2, "--max-ranges"),
    ("recover-nothing-salvageable", "truav", "log recover {header_only_mcap} {dir}/fixed.mcap", 1,
     "nothing salvageable"),
    ("recover-out-under-file", "truav", "log recover {good_mcap} {a_file}/fixed.mcap", 2, "OUT"),
    ("cut-corrupt", "truav", "log cut {corrupt_mcap} {dir}/cut-corrupt.mcap", 1, "corrupt.mcap"),
    ("cut-unfinished", "truav", "log cut {unfinished_mcap} {dir}/cut.mcap", 2, "truav log recover"),
    ("cut-out-under-file", "truav", "log cut {good_mcap} {a_file}/cut.mcap", 2, "OUT"),
    ("cut-tick-negative", "truav", "log cut {good_mcap} {dir}/cut.mcap --from-tick -1", 2, "--from-tick"),
    ("merge-corrupt", "truav", "log merge {dir}/merged-corrupt.mcap {good_mcap} {corrupt_mcap}", 1, "corrupt.mcap"),
    ("info-random-bytes", "truav", "log info {good_mcap} {random_toml}", 2, "random.toml"),
    ("info-parts-index", "truav", "log info {run_parts_json}", 2, "truav log merge ALL.mcap"),
    ("cut-parts-index", "truav", "log cut {run_parts_json} {dir}/cut.mcap", 2, "parts index"),
    ("cut-window-after-the-end", "truav", "log cut {good_mcap} {dir}/cut.mcap --start 1000", 2,
     "the window [1000.000 s, last message] holds no message"),
    ("cut-window-reversed", "truav", "log cut {good_mcap} {dir}/cut.mcap --start 0.5 --end 0.2", 2,
     "(start 0.500 s, end 0.200 s from the first message)"),
    ("merge-same-file-twice", "truav", "log merge {dir}/merged.mcap {good_mcap} {good_mcap}", 2, "named twice"),
    ("resim-no-tick", "truav", "log resim {no_ticks_mcap}", 2, "nothing to re-simulate"),
    ("resim-one-part", "truav", "log resim {run_0002_mcap}", 2, "part 2 of a split recording"),
    ("resim-parts-index", "truav", "log resim {run_parts_json}", 2, "truav log merge ALL.mcap"),
    ("record-summary-json-is-the-recording", "truav", "log record --run r --out {dir}/r.mcap --summary-json "
     "{dir}/r.mcap", 2, "--summary-json"),
    ("record-summary-json-a-directory", "swarm", "record --run r --out {dir}/r.mcap --summary-json {dir}", 2,
     "--summary-json"),
    # truav-swarm up / chaos
    ("up-listen-garbage", "swarm", "up -l garbage", 2, "-l/--listen"),
    ("up-two-listens", "swarm", "up -l tcp/127.0.0.1:7447 -l tcp/127.0.0.1:7448", 2, "-l/--listen"),
    ("up-out-is-file", "swarm", "up --out {a_file}", 2, "--out"),
    ("up-out-under-file", "swarm", "up --out {a_file}/swarm", 2, "--out"),
    ("up-record-under-file", "swarm", "up --record {a_file}/run.mcap", 2, "--record"),
    ("up-plan-random-bytes", "swarm", "up --fault-plan {random_toml}", 2, "random.toml"),
    ("up-scenario-random-bytes", "swarm", "up --scenario {random_toml}", 2, "random.toml"),
    ("up-plan-uav-99", "swarm", "up --fault-plan {uav99_toml}", 2, "UAV 99"),
    ("up-plan-malformed-glob", "swarm", "up --fault-plan {badglob_toml}", 2, "badglob.toml"),
    ("up-plan-glob-matches-nothing", "swarm", "up --fault-plan {typoglob_toml}", 2, "typoglob.toml"),
    ("up-agents-500", "swarm", "up --agents 500", 2, "--force-agents"),
    ("up-n-uavs-300", "swarm", "up --set scenario.n_uavs=300", 2, "--force-agents"),
    ("up-agents-contradicts-set", "swarm", "up --agents 8 --set scenario.n_uavs=5", 2, "--agents"),
    ("up-seed-negative", "swarm", "up --seed -1", 2, "--seed"),
    ("up-qtable-empty", "swarm", "up --qtable {run_empty}", 2, "--qtable"),
    ("up-qtable-wrong-shape", "swarm", "up --qtable {run_shape}", 2, "--qtable"),
    ("up-run-slash", "swarm", "up --run a/b", 2, "--run"),
    ("up-patrol-qtable", "swarm", "up --scheme patrol --qtable {run_shape}", 2, "--qtable"),
    ("up-truav-policy", "swarm", "up --policy {dir}", 2, "--policy"),
    ("up-central-policy-missing", "swarm", "up --scheme central --policy {dir}", 2, "--policy"),
    ("up-truav-command-hold", "swarm", "up --command-hold 3", 2, "--command-hold"),
    ("up-truav-plan-kills-controller", "swarm", "up --fault-plan {ctrl_toml}", 2, "names the controller"),
    ("up-central-upload-too-big", "swarm", "up --scheme central --set central.upload_bytes=100000", 2,
     "central.upload_bytes"),
    ("faults-policy-without-central", "truav", "experiment faults --quick --schemes truav --policy {dir}", 2,
     "--policy"),
    ("chaos-fault-plan-ignored", "swarm", "chaos --plan {plan_toml} --fault-plan {plan_toml}", 2, "--fault-plan"),
    ("chaos-plan-random-bytes", "swarm", "chaos --plan {random_toml}", 2, "random.toml"),
    ("chaos-plan-uav-99", "swarm", "chaos --plan {uav99_toml}", 2, "UAV 99"),
    # truav-swarm: the other commands
    ("status-run-slash", "swarm", "status --run a/b", 2, "--run"),
    ("down-run-slash", "swarm", "down --run a/b", 2, "--run"),
    ("faults-run-slash", "swarm", "faults --run a/b --plan {plan_toml}", 2, "--run"),
    ("faults-plan-random-bytes", "swarm", "faults --plan {random_toml}", 2, "random.toml"),
    ("status-connect-garbage", "swarm", "status -e garbage", 2, "-e/--connect"),
    ("status-config-missing", "swarm", "status -c {dir}/nope.json5", 2, "-c/--config"),
    ("status-out-without-run", "swarm", "status --out {dir}/no_run_here", 2, "--out"),  # not the default endpoint
    ("down-out-without-run", "swarm", "down --out {dir}", 2, "--out"),
    ("down-out-garbage-endpoint", "swarm", "down --out {bad_run_dir}", 2, "endpoint"),
    ("down-no-such-run", "swarm", "down --run nosuch", 2, "no such run: runs/swarm-nosuch/swarm.json does not exist"),
    ("down-run-ended", "swarm", "down --out {ended_run}", 2, "has ended"),
    ("status-run-ended", "swarm", "status --out {ended_run}", 2, "has ended"),
    ("down-supervisor-gone", "swarm", "down --out {dead_run}", 2, "is not running"),
    ("down-tls-without-creds", "swarm", "down --out {tls_run}", 2, "--creds"),
    ("status-tls-without-creds", "swarm", "status -e tls/127.0.0.1:7447", 2, "--creds"),
    ("world-config-json5-syntax", "swarm", "world -c {unclosed_json5}", 2, "-c/--config"),  # json5's caret diagram
    ("up-record-in-proc", "swarm", "up --record /proc/truav-test.mcap", 2, "--record"),  # root may "access" it
    ("train-out-in-proc", "truav", "train --out /proc/truav-test", 2, "--out"),
    ("router-listen-garbage", "swarm", "router -l garbage", 2, "-l/--listen"),
    ("world-plan-uav-99", "swarm", "world --fault-plan {uav99_toml}", 2, "UAV 99"),
    ("world-seed-negative", "swarm", "world --seed -1", 2, "--seed"),
    ("agent-id-negative", "swarm", "agent --id -1", 2, "--id"),
    ("up-lockstep-wait-real-time", "swarm", "up --lockstep-wait 5", 2, "--lockstep-wait"),
    ("up-snapshots-unrecorded", "swarm", "up --lockstep --snapshot-every 5", 2, "--snapshot-every"),
    ("up-snapshots-negative", "swarm", "up --snapshot-every -1", 2, "--snapshot-every"),
    ("agent-lockstep-wait-real-time", "swarm", "agent --id 0 --lockstep-wait 5", 2, "--lockstep-wait"),
    ("world-lockstep-wait-zero", "swarm", "world --lockstep --lockstep-wait 0", 2, "--lockstep-wait"),
    ("agent-checkpoint-empty", "swarm", "agent --id 0 --checkpoint {empty_npz}", 2, "--checkpoint"),
    ("agent-qtable-foreign", "swarm", "agent --id 0 --qtable {run_foreign}", 2, "--qtable"),
    ("agent-qtable-truncated", "swarm", "agent --id 0 --qtable {run_trunc}", 2, "--qtable"),
    ("agent-qtable-wrong-shape", "swarm", "agent --id 0 --qtable {run_shape}", 2, "--qtable"),
    ("record-router-wait-nan", "swarm", "record --run r --out {dir}/r.mcap --router-wait nan", 2, "--router-wait"),
    ("record-config-random", "swarm", "record --run r --out {dir}/r.mcap --config-toml {random_toml}", 2,
     "random.toml"),
    ("record-out-under-file", "swarm", "record --run r --out {a_file}/r.mcap", 2, "--out"),
    ("replay-connect-garbage", "swarm", "replay {good_mcap} -e garbage", 2, "-e/--connect"),
    ("replay-topics-match-nothing", "swarm", "replay {good_mcap} --topics truav/*/world/nothing", 2, "--topics"),
    ("replay-corrupt-mcap", "swarm", "replay {corrupt_mcap}", 1, "corrupt.mcap"),
    ("replay-lockstep-wait-zero", "swarm", "replay {good_mcap} --lockstep --lockstep-wait 0", 2, "--lockstep-wait"),
    ("replay-same-file-twice", "swarm", "replay {good_mcap} {good_mcap}", 2, "named twice"),
    ("replay-ctl-rate-zero", "swarm", "replay-ctl rate 0", 2, "R"),
    ("replay-ctl-seek-nowhere", "swarm", "replay-ctl seek", 2, "--tick"),
    ("replay-ctl-seek-twice", "swarm", "replay-ctl seek --tick 3 --time 1", 2, "--time"),
    ("replay-ctl-seek-tick-negative", "swarm", "replay-ctl seek --tick -1", 2, "--tick"),
    ("replay-ctl-bad-run", "swarm", "replay-ctl --run a.b status", 2, "--run"),
    ("replay-ctl-step-zero", "swarm", "replay-ctl step 0", 2, "N"),
    ("certs-out-under-a-file", "swarm", "certs --out /dev/null/creds", 2, "--out"),
    ("deploy-configs-out-under-a-file", "swarm", f"deploy-configs {DEPLOYMENT} --out {{a_file}}/x", 2, "--out"),
    # an --out mistake is told before the SUMO trace is built (minutes the first time), not after
    # a plan's process faults would be dropped by every receiver of `faults`: refused, not sent without them
    ("faults-crash-plan", "swarm", "faults --run demo --plan {uav99_toml}", 2, "--plan"),
    ("up-sumo-out-holds-a-run", "swarm", "up --mobility sumo --out {earlier_run}", 2, "--out"),
]


def _argv(argv: str | list[str], files: dict[str, str]) -> list[str]:
    return [a.format(**files) for a in (argv.split() if isinstance(argv, str) else argv)]


@pytest.mark.parametrize("main, argv, code, names", [r[1:] for r in ROWS], ids=[r[0] for r in ROWS])
def test_bad_invocation_is_one_line(files, nothing_starts, capsys, main, argv, code, names) -> None:
    entry = truav_main if main == "truav" else swarm_main
    try:
        rc = entry(_argv(argv, files))
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert rc == code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert names in lines[0], lines[0]


def test_quick_does_not_override_explicit_settings(files, tmp_path, monkeypatch) -> None:
    """--quick fills in what the user left out; --set and flags given explicitly win."""
    from truav.cli import experiment as ex_cli
    seen = {}

    def capture(args, cfg, out, cells, label):
        seen.update(cfg=cfg, cells=cells)
        raise SystemExit(0)

    monkeypatch.setattr(ex_cli, "_run", capture)
    with pytest.raises(SystemExit):
        truav_main(["experiment", "velocity", "--quick", "--set", "scenario.n_vehicles=90", "--episodes", "7",
                    "--out", str(tmp_path / "v"), "--schemes", "truav"])
    assert seen["cfg"].scenario.n_vehicles == 90
    assert seen["cfg"].scenario.steps_per_episode == ex_cli.QUICK_CONFIG["scenario"]["steps_per_episode"]
    assert {c.episodes for c in seen["cells"]} == {7}


def test_fault_sweep_keeps_explicit_episode_length(tmp_path, monkeypatch) -> None:
    """The sweep's own episode length gives way to a scenario.steps_per_episode the user set."""
    import truav.swarm.fault_sweep as sweep
    seen = []
    monkeypatch.setattr(sweep, "run_sweep", lambda cfg, size, out, **kw: seen.append((cfg, kw)) or out / "f.png")
    for n, extra in enumerate(([], ["--set", "scenario.steps_per_episode=30"])):
        assert truav_main(["experiment", "faults", "--quick", "--out", str(tmp_path / str(n)), *extra]) == 0
    assert [kw["keep_steps"] for _, kw in seen] == [False, True]
    assert seen[1][0].scenario.steps_per_episode == 30


def test_fault_experiment_resumes_its_out_only_with_the_same_settings(tmp_path, monkeypatch, capsys) -> None:
    """A re-run into --out keeps its finished points: with another seed or scenario it used to reuse them
    silently (a 2-UAV comparison relabelled as seed 9 with 3 UAVs in 1.5 s, exit 0); now refused in one line
    before anything runs, and the same options still resume."""
    import truav.swarm.fault_sweep as sweep
    import truav.swarm.scheme_faults as scheme_faults
    runs = []
    monkeypatch.setattr(scheme_faults, "run_comparison", lambda cfg, size, out, schemes, **kw: runs.append(kw) or [])
    monkeypatch.setattr(sweep, "run_sweep", lambda cfg, size, out, **kw: runs.append(kw) or out / "f.png")
    out = str(tmp_path / "cmp")
    argv = ["experiment", "faults", "--quick", "--schemes", "patrol", "--out", out, "--set", "scenario.n_uavs=2"]
    assert truav_main(argv) == 0
    assert truav_main(argv + ["--schemes", "patrol", "central"]) == 0  # more schemes: the same points' settings
    capsys.readouterr()
    for other in (["--seed", "9"], ["--set", "scenario.n_uavs=3"], ["--rate", "20"]):
        assert truav_main(argv + other) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--out" in err[0] and "other settings" in err[0], err
    assert truav_main(["experiment", "faults", "--quick", "--out", out]) == 2  # the sweep's points are not these
    assert len(runs) == 2
    legacy = tmp_path / "legacy"
    (legacy / "patrol-none-0").mkdir(parents=True)
    (legacy / "patrol-none-0" / "summary.json").write_text("{}")  # a point, and no settings.json
    assert truav_main(argv[:-4] + ["--out", str(legacy)]) == 2


def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL, cwd=cwd,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})


@pytest.mark.parametrize("cmd, code, names", [
    (["truav", "train", "--seed-start", "-1"], 2, "--seed-start"),
    (["truav-swarm", "up", "-l", "garbage"], 2, "-l/--listen"),
    (["truav-swarm", "status", "--run", "a/b"], 2, "--run"),
    (["truav", "log", "check", "{unfinished_mcap}"], 1, "truav log recover"),
    (["truav", "log", "record-ctl", "split", "-e", "tcp/127.0.0.1:1", "--wait", "0.5"], 1, "cannot open a session"),
])
def test_real_entry_points(files, tmp_path, cmd, code, names) -> None:
    proc = _run([sys.executable, "-c", f"import sys; from {'truav.cli.main' if cmd[0] == 'truav' else 'truav.cli.swarm'} "
                 f"import main; sys.exit(main())", *_argv(cmd[1:], files)], cwd=tmp_path)
    assert "Traceback" not in proc.stderr
    assert proc.returncode == code, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and names in proc.stderr


def test_log_recover_into_a_new_directory(files, tmp_path, capsys) -> None:
    """OUT's directory is made, as cut and merge make it (it was checked creatable, then the write failed)."""
    out = tmp_path / "new" / "fixed.mcap"
    assert truav_main(["log", "recover", files["unfinished_mcap"], str(out)]) == 0, capsys.readouterr().err
    assert truav_main(["log", "check", str(out)]) == 0


def test_log_check_into_a_closed_pipe_ends_quietly(files, tmp_path) -> None:
    """`truav log check FILE | head`: the reader goes away; no BrokenPipeError traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # nobody reads: the first write fails with EPIPE
    try:
        proc = subprocess.run([sys.executable, "-c", "import sys; from truav.cli.main import main; sys.exit(main())",
                               "log", "check", files["good_mcap"]], stdout=write_end, stderr=subprocess.PIPE,
                              text=True, timeout=60, stdin=subprocess.DEVNULL, cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    finally:
        os.close(write_end)
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr, proc.stderr
    assert proc.returncode == 141  # 128 + SIGPIPE, what a shell reports for a Unix tool in this spot


def test_log_check_is_quiet_and_zero_on_a_complete_recording(files, capsys) -> None:
    assert truav_main(["log", "check", files["good_mcap"]]) == 0
    out, err = capsys.readouterr()
    assert ": finished" in out and err == ""


def test_a_tls_router_asked_without_credentials_says_credentials_are_needed(tmp_path, capsys) -> None:
    """A --secure swarm's router at a tcp/ endpoint: Zenoh says only that it cannot connect; the router
    answers a probe in TLS, so the command says credentials are needed (one line, exit 2)."""
    import zenoh
    from tests.support.waits import free_port
    from truav.bus import security
    port = free_port()
    security.issue(tmp_path, "sec", 2, f"tcp/127.0.0.1:{port}")
    router = zenoh.open(zenoh.Config.from_file(str(tmp_path / security.ROUTER_CONFIG)))
    try:
        rc = swarm_main(["status", "--run", "sec", "-e", f"tcp/127.0.0.1:{port}"])
    finally:
        router.close()
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "speaks TLS" in err and "--creds" in err, err
