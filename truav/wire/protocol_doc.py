"""The tables of docs/reference/protocol.md that come from the schema, generated (pure: text in, text out).

Each table is built from the schema itself: the message kinds from the registry
(:data:`truav.wire.messages.MESSAGE_CLASSES`, so a kind added there appears here), each field's wire type
and range from its check (:mod:`truav.wire.field_checks`, read from the check's closure), keys from each
kind's ``PLACE``, limits from :mod:`truav.wire.schema_names` and the codec's msgpack limits, the refusal
reasons from the ``R_*`` constants, the action numbering from the world's own velocity table
(``world.uavs.ACTION_UNIT_VELOCITY``). What cannot be read from code (a field's unit and meaning, who
sends a kind) is kept here by hand, next to the tables, in :data:`FIELD_NOTES` and friends; a field or
reason without a note is rendered with :data:`NO_NOTE`, which tests/docs/test_protocol_doc.py refuses.

The document keeps its prose by hand and holds each table between two markers::

    <!-- generated: NAME -->
    ...
    <!-- end generated: NAME -->

:func:`render_into` replaces what is between them; ``truav-swarm schema --doc docs/reference/protocol.md``
rewrites the file (``--check``: only says whether it is up to date).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from truav.actions import HOVER, N_ACTIONS
from truav.wire import guard, keys, schema_names
from truav.wire.codec import unpack_limits
from truav.wire.field_checks import _name
from truav.wire.messages import (DEFAULT_LOCKSTEP_WAIT_S, HEALTH_PERIOD_S, LOCKSTEP_JOIN_GRACE_S, MESSAGE_CLASSES,
                                REJECTION_PERIOD_S, size_limit)
from truav.wire.schema_names import SCHEMA_VERSION, _ENVELOPE_KEYS
from world.uavs import ACTION_UNIT_VELOCITY

NO_NOTE = "(no note: add one to truav/wire/protocol_doc.py)"
KEY_MISMATCH = "key_mismatch"
"""truav.bus.placement.R_KEY_MISMATCH (a bus-layer module, not imported here; the test checks they agree)."""

# --- what cannot be read from the code: who sends what, units, meanings ------------------------------
SENDERS: Mapping[str, tuple[str, str]] = {
    "tick": ("world", "all"),
    "obs": ("world", "agent i"),
    "beacon": ("uav/i", "all agents (and recorder, supervisor)"),
    "action": ("uav/i", "world"),
    "metrics": ("world", "recorder, supervisor, status"),
    "fault": ("supervisor", "all"),
    "control": ("supervisor (world: `shutdown`)", "all"),
    "positions": ("world", "recorder"),
    "state": ("uav/i", "central controller (scheme central)"),
    "command": ("controller", "agent i (scheme central)"),
    "health": ("uav/i", "supervisor, status, recorder"),
    "beacons": ("uav/<first> of the group", "all agents (--batch-beacons)"),
    "rejection": ("world", "agent i only (under --secure no other identity may read it)"),
    "replay_status": ("replay", "operator (`truav-swarm replay-ctl`), recorder"),
    "world_snapshot": ("world", "recorder (lock-step, --snapshot-every)"),
    "agent_snapshot": ("uav/i", "recorder (lock-step, --snapshot-every)"),
    "qshare": ("uav/i", "all agents (federated TRUAV, federated.every > 0), recorder"),
    "override": ("operator or supervisor", "world (and recorder)"),
}
"""Per kind: (the only ``src`` the guard accepts, who listens)."""

KEY_TAILS: Mapping[str, str] = {
    keys.METRICS_ROOT: "<scope>",
    keys.FAULT_ROOT: "<fault>",
    keys.CONTROL_ROOT: "<part>[/<part>...]",
    keys.CONTROLLER: f"{keys.COMMAND}/<i>",
    "group": "<first>-<last>/beacons",  # --batch-beacons: one process's UAVs first..last
    keys.REPLAY_ROOT: keys.REPLAY_STATUS,  # replay/ctl is a queryable, not a put
}
"""The key chunks after a one-chunk ``PLACE`` (the rest of the key names the instance)."""

_C = {  # values the notes quote
    "area": f"[-{guard.AREA_MARGIN_M:g}, area_m + {guard.AREA_MARGIN_M:g}]",
    "speed": f"scenario.uav_speed_mps x {guard.SPEED_MARGIN:g}",
    "window": f"+-{guard.TICK_WINDOW}",
}
_TICK = f"tick; guard: within {_C['window']} of the receiver's current tick"
_UAV_NOTE = "the UAV's id, the `<i>` of the key and of `src` `uav/<i>`; guard: < the scenario's n_uavs"
_COUNT = "guard: <= scenario.n_vehicles"
_PACKETS = "guard: <= scenario.n_vehicles x traffic.queue_limit"
_ENERGY = "guard: <= 1e5 x scenario.step_s"
_POS = f"[x, y] in the square area [0, area_m]; guard: both in {_C['area']}"

ENVELOPE_NOTES: Mapping[str, tuple[str, str]] = {
    "v": ("", "schema version"),
    "kind": ("", "message kind: which table below the rest of the map follows"),
    "src": ("", "sender identity: `world`, `uav/<i>`, `controller`, `supervisor`, `operator`, `recorder`, `fault`, "
                "`replay`; "
                "must match the key and the kind (see Keys)"),
    "seq": ("", "per sender, per kind: 0, 1, 2, ... (a gap means messages were lost; a restart begins at 0 "
                "with a new `inc`)"),
    "t": ("ns", "sender's wall clock when sent, nanoseconds since the Unix epoch (e.g. `time.time_ns()`)"),
    "inc": ("", "incarnation: a random 63-bit id drawn once per process start, not 0; 0 means unknown"),
}

FIELD_NOTES: Mapping[str, Mapping[str, tuple[str, str]]] = {
    "tick": {
        "tick": ("", "tick number, from 0, +1 per round over the whole run (episodes do not restart it)"),
        "episode": ("", "episode index, from 0"),
        "sim_time": ("s", "simulated time: tick x scenario.step_s"),
        "deadline_ms": ("ms", "real time: the answer's deadline, deadline_frac (0.8) of the tick period after "
                              "the tick's scheduled start; lock-step: how long the world waits for a live agent "
                              "(--lockstep-wait)"),
        "n_uavs": ("", "UAVs of the scenario; guard: equal to the receiver's"),
    },
    "obs": {
        "tick": ("", "the round this observation opens: answer it with this tick"),
        "episode": ("", "episode index; a new value starts an episode (no reward for its first observation)"),
        "uav": ("", _UAV_NOTE),
        "pos": ("m", f"the UAV's position, {_POS}"),
        "vehicles_in_range": ("vehicles", f"vehicles within scenario.comm_range_m; {_COUNT}"),
        "queued_packets": ("packets", f"packets queued at the vehicles this UAV serves; {_PACKETS}"),
        "relayed": ("packets", f"packets this UAV relayed to the roadside units in the last step; {_PACKETS}"),
        "covered": ("vehicles", f"vehicles this UAV served (nearest UAV in range) in the last step; {_COUNT}"),
        "energy_j": ("J", f"energy the UAV spent in the last step (flight and transmission); {_ENERGY}"),
        "speed_max": ("m/s", f"the UAV's full speed: an action flies half or all of it; guard: <= {_C['speed']}"),
        "done": ("", "true on an episode's last observation: learn from it, do not act (see the rules)"),
        "densest_sector": ("", "with sensing on (learner.sense_range_m > 0): 1 + the direction sector holding "
                               "the most vehicles beyond comm range and within the sensing radius (see "
                               "densest_sector); 0: none sensed, or sensing off"),
        "exclusive": ("vehicles", "vehicles within this UAV's comm range and no other UAV's: the coverage the "
                              f"swarm would lose without it (the difference reward, learner.w_difference); {_COUNT}"),
        "disc_offset": ("m", "with sensing on and learner.sense_disc: among the vehicles within the sensing radius, "
                             "the one with the most vehicles within comm range of it, its position minus the UAV's "
                             "[dx, dy]; [0, 0]: none sensed, or off (absent from older senders: [0, 0])"),
        "disc_vehicles": ("vehicles", "the vehicles within comm range of that centre, itself counted; 0: none sensed, "
                                      f"or off (absent from older senders: 0); {_COUNT}"),
    },
    "beacon": {
        "uav": ("", _UAV_NOTE),
        "tick": ("", f"the tick of the observation it answers; {_TICK}"),
        "pos": ("m", f"the position that observation gave, {_POS}"),
        "vel": ("m/s", f"[vx, vy], the velocity of the UAV's last action (0, 0 before any); guard: norm <= "
                       f"{_C['speed']}"),
        "fields": ("", "what an agent-API class's beacon_fields() returned after its last action "
                       "(`truav-swarm up --agent NAME`); peers hear them in their next view; TRUAV sends none"),
    },
    "action": {
        "uav": ("", _UAV_NOTE),
        "tick": ("", f"the tick of the observation it answers; {_TICK}; one action per UAV per tick"),
        "action": ("", f"see Action numbering; {HOVER}: hover"),
    },
    "metrics": {
        "scope": ("", "`step` (each tick) or `episode` (each episode's end), also the key's last chunk"),
        "tick": ("", "the tick they describe"),
        "episode": ("", "the episode they describe"),
        "values": ("", "named finite numbers: step: covered, generated, delivered, dropped, delay_sum_s, "
                       "energy_j, hovering_uavs, coverage_pct, rejected, rejected.<reason>; episode: its summary"),
    },
    "fault": {
        "fault": ("", "fault kind (loss, latency, partition, crash, freeze), also the key's last chunk"),
        "phase": ("", "the fault starts or ends"),
        "target": ("", "what it applies to, as the fault plan names it (truav/faults.py)"),
        "params": ("", "the fault's parameters by name (truav/faults.py)"),
    },
    "control": {
        "command": ("", "what to do: `shutdown` (on control/shutdown: the run is over, exit), a fault plan, ..."),
        "args": ("", "its arguments (`{}` for shutdown)"),
    },
    "positions": {
        "tick": ("", "the tick they were taken at (every few ticks)"),
        "uavs": ("m", "every UAV's [x, y], in id order; guard: exactly n_uavs"),
        "vehicles": ("m", f"vehicles' [x, y], rounded to a grid; {_COUNT}"),
    },
    "state": {
        "uav": ("", _UAV_NOTE), "tick": ("", _TICK), "episode": ("", "episode index"),
        "step": ("", "step within the episode"), "pos": ("m", _POS),
        "vehicles_in_range": ("vehicles", _COUNT), "queued_packets": ("packets", _PACKETS),
        "relayed": ("packets", _PACKETS), "covered": ("vehicles", _COUNT), "energy_j": ("J", _ENERGY),
        "done": ("", "the episode's last observation"),
        "pad": ("bytes", "padding to central.upload_bytes (the modelled report size); content ignored"),
    },
    "command": {
        "uav": ("", _UAV_NOTE), "tick": ("", f"the first tick to fly it; {_TICK}"),
        "action": ("", "see Action numbering (no hover)"),
        "pad": ("bytes", "padding to central.download_bytes; content ignored"),
    },
    "health": {
        "uav": ("", _UAV_NOTE),
        "last_tick": ("", "the last observation's tick it answered (-1: none yet)"),
        "steps": ("", "learning steps so far"),
        "stale_obs_skipped": ("", "real time: observations skipped because a newer one was waiting"),
        "rejected": ("", "messages it refused so far, by reason (the table of reasons)"),
        "senders": ("", "messages it refused so far, by sender: only the most refused"),
        "heard": ("beacons", "beacons this process heard so far from each UAV (index: sender id; its own 0), "
                             "after the fault plan's link faults; optional (an older report: empty)"),
    },
    "rejection": {
        "uav": ("", "the UAV of the key the refused messages came on (`uav/<i>/...`), never read from their "
                    "payload"),
        "at_tick": ("", "the refused action's own tick (`late_action`, `stale_action`), else the world's latest "
                        "tick when it refused the message; -1: before tick 0"),
        "reason": ("", "reason code (the table of reasons) of the first message refused since the last rejection"),
        "refused_kind": ("", "the kind that message's key carries (`action`); empty for a key of no kind"),
        "key": ("", "the key it came on"),
        "detail": ("", "what was wrong with it, in words (cut to 160 printable ASCII characters)"),
        "counts": ("", "every message of this UAV refused since the last rejection, by reason (the first "
                       "included): a flood is summed here, not answered one by one"),
    },
    "replay_status": {
        "state": ("", "playing, paused, waiting (--lockstep: for the live agents' answers) or ended"),
        "position_s": ("s", "receive time of the last message sent, from the recording's first message"),
        "span_s": ("s", "the recording's length, first to last message"),
        "tick": ("", "the last world tick sent (-1: none yet)"),
        "rate": ("", "speed factor (2: twice as fast as recorded)"),
        "paused": ("", "true while paused (a step or burst leaves it paused)"),
        "sent": ("messages", "recorded messages sent so far (again after a seek back)"),
        "restored": ("messages", "messages re-sent after seeks: each channel's last value before the new position"),
        "loop": ("", "complete passes so far (--loop)"),
    },
    "qshare": {
        "uav": ("", _UAV_NOTE),
        "tick": ("", f"the tick of the episode's last observation it was made at; {_TICK}"),
        "episode": ("", "the episode it was made after: its share round ((episode + 1) % federated.every == 0); "
                        "receivers refuse an older round's share (stale_round), and one not of a share round or "
                        "further ahead than the few nearest rounds they keep (bad_round)"),
        "part": ("", "which part of the share, also the key's last chunk `<n>`"),
        "parts": ("", "how many parts the share has; a receiver merges a share once it has every part, else not "
                      "at all"),
        "states": ("", "the states of the rows, distinct, each < the receiver's number of states "
                       "(learner state design): the states the UAV visited since its last share, most visited first"),
        "counts": ("updates", "per state, how many Q updates the UAV made in it so far (its visit count), "
                              "<= (episode + 1) x steps_per_episode"),
        "q": ("", "the rows, row-major: 16 values per state (action order of Action numbering); each finite, "
                  "|value| <= federated.q_bound, else the whole share is refused"),
    },
    "override": {
        "uav": ("", "the UAV to steer, the `<i>` of the key; guard: < the scenario's n_uavs"),
        "release": ("", "true ends the override: the agent flies the UAV again (goal and speed are not read)"),
        "goal": ("m", f"[x, y] to fly to (world.steer: the one of the 16 actions that gets nearest it, hover "
                      f"within one step); guard: both in {_C['area']} unless released"),
        "speed": ("m/s", "the half or full speed of the actions nearest to it; 0 or above the UAV's: full speed"),
    },
    "beacons": {
        "entries": ("m, m/s", "one process's beacons of a tick, each [uav, tick, [x, y], [vx, vy]] with a "
                              "beacon's meaning and bounds; only the UAVs first..last of the key, each once"),
    },
    "world_snapshot": {
        "tick": ("", "the state is the world's before this tick's round (what `truav log resim --from` restores)"),
        "episode": ("", "the episode of that tick"),
        "arrays": ("", "the world's whole state, named arrays (world/world_state.py): vehicles, queues, UAVs, "
                       "totals, generators now and before the episode's draws"),
    },
    "agent_snapshot": {
        "uav": ("", _UAV_NOTE),
        "tick": ("", "the state is the agent's before this tick's observation"),
        "arrays": ("", "its decision state (agents/decision_state.py): the Q-table rows it updated (q_rows, "
                       "q_values), its generator, the episode's exploration draws"),
    },
}

REASON_NOTES: Mapping[str, str] = {
    "not_bytes": "the payload is not bytes",
    "too_large": "larger than the kind's size limit, or a msgpack length above the kind's limits",
    "not_msgpack": "not one complete msgpack value (trailing bytes included)",
    "not_map": "the top level is not a map",
    "bad_version": "`v` missing or not the schema version",
    "unknown_kind": "`kind` is not one of the kinds",
    "missing_field": "a field of the kind (envelope included) is missing",
    "extra_field": "a key the kind does not have",
    "bad_type": "a field of the wrong type (an int for a bool, a float for an int, ...)",
    "out_of_range": "a value outside its range (the tables above), a string too long or with other characters",
    "unstamped": "`src` is empty",
    KEY_MISMATCH: "the message does not belong on its key: another kind, another UAV's id, a `uav/<j>` sender "
                  "on another UAV's key, a metrics scope or fault kind other than the key's last chunk",
    "forbidden_sender": "`src` may not send that kind (Keys: sender), e.g. a beacon of uav 2 from `uav/1`",
    "implausible": "a value the scenario cannot produce (the guard's bounds in the field tables)",
    "tick_out_of_window": f"a tick more than {guard.TICK_WINDOW} from the receiver's current tick",
    "duplicate_action": "a second action of one UAV for one tick",
    "replayed": "traffic a replay put into a live run (refused unless the receiver accepts replays)",
    "late_action": "(world, told in a rejection only) a valid action that came after its round closed: not "
                   "applied, counted in `late`",
    "stale_action": "(world, told in a rejection only) a valid action for an older tick than one the same UAV "
                    "already answered: not applied, counted in `stale`",
}


# --- reading a field check ---------------------------------------------------------------------------
def _big(n: int) -> str:
    for bits in (63, 64):
        if n == (1 << bits) - 1:
            return f"2^{bits}-1"
        if n == -(1 << bits):
            return f"-2^{bits}"
    return str(n)


def _closure(check: Any) -> dict[str, Any]:
    names = check.__code__.co_freevars
    return dict(zip(names, (cell.cell_contents for cell in check.__closure__ or ())))


def describe(check: Any) -> tuple[str, str]:
    """(msgpack type, accepted values) of a field check; ValueError for a check it cannot read, so
    a new kind of check is described deliberately."""
    name = getattr(check, "__qualname__", "")
    v = _closure(check) if getattr(check, "__closure__", None) else {}
    if name == "_int.<locals>.check":
        return "int", f"[{_big(v['lo'])}, {_big(v['hi'])}]"
    if name == "_real.<locals>.check":
        lo = v["lo"]
        bound = "" if lo is None else (f" > {lo:g}" if v["lo_open"] else f" >= {lo:g}")
        return "float64 (an int is accepted)", f"finite{bound}"
    if name == "_bool":
        return "bool", "true, false"
    if name == "_text.<locals>.check":
        pattern = v["pattern"]
        chars = f" of `{pattern.pattern}`" if pattern is not None else ""
        return "str", f"{0 if v['allow_empty'] else 1}..{v['max_len']} characters{chars}"
    if name == "_choice.<locals>.check":
        return "str", "one of " + ", ".join(f"`{o}`" for o in v["options"])
    if name == "_vec2":
        return "array of 2 float64", "[x, y], finite"
    if name == "_points.<locals>.check":
        return "array of [x, y] (2 float64 each)", f"at most {v['max_n']} points, finite"
    if name == "_str_map.<locals>.check":
        vt, vr = describe(v["value_check"])
        kt, kr = describe(_name)
        return f"map {kt} -> {vt}", f"at most {v['max_entries']} entries; keys {kr}; values {vr}"
    if name == "_count_map.<locals>.check":
        kt, kr = describe(v["key_check"])
        return f"map {kt} -> int", f"at most {v['max_entries']} entries; keys {kr}; counts [0, 2^63-1]"
    if name == "_pad":
        return "bin", f"at most {schema_names.MAX_SMALL_PAYLOAD_BYTES} bytes"
    if name == "_param_value":
        return "int, float64 or str", (f"int64, finite float, or a str of 0..{schema_names.MAX_PARAM_STR_LEN} "
                                       f"characters")
    if name == "_json_like":
        return "map (JSON-like: nil, bool, int, float64, str, array, map)", (
            f"nesting <= {schema_names.MAX_ARGS_DEPTH}, <= {schema_names.MAX_ARGS_NODES} values, strings <= "
            f"{schema_names.MAX_ARGS_STR_LEN} characters, map keys str <= {schema_names.MAX_NAME_LEN}")
    if name == "_snapshot_arrays":  # a snapshot's named state arrays (--snapshot-every)
        return "map of str: [dtype, shape, bin]", (
            f"<= {schema_names.MAX_SNAPSHOT_ARRAYS} arrays, names as metric names; dtype one of "
            f"{', '.join(schema_names.SNAPSHOT_DTYPES)}; shape <= {schema_names.MAX_SNAPSHOT_DIMS} lengths; "
            f"data exactly 8 bytes per element")
    if name == "_ints.<locals>.check":
        return "array of int", f"at most {v['max_n']} values, each in [{_big(v['lo'])}, {_big(v['hi'])}]"
    if name == "_counts.<locals>.check":
        return "array of int", f"at most {v['max_n']} values, each in [0, 2^63-1]"
    if name == "_floats.<locals>.check":
        return "array of float64 (ints accepted)", f"at most {v['max_n']} values, each finite"
    if name == "_beacon_entries":  # the batched beacons' entries (--batch-beacons)
        return "array of [int, int, [x, y], [vx, vy]]", (f"1..{keys.MAX_UAVS} entries: uav [0, {keys.MAX_UAVS - 1}], "
                                                          f"tick [0, 2^63-1], finite float64 pairs")
    if name == "_beacon_fields":  # an API agent's beacon_fields(), sent only if any
        return "map str -> bool, int or float64", (
            f"optional (left off when empty); at most {schema_names.MAX_BEACON_FIELDS} entries; keys printable "
            f"ASCII of 1..{schema_names.MAX_BEACON_FIELD_NAME} characters; values bool, int64 or finite float")
    raise ValueError(f"protocol_doc.describe: cannot read the check {name or check!r}; teach it this check")


# --- the tables ----------------------------------------------------------------------------------------
def _row(*cells: str) -> str:
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def _table(head: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    return "\n".join([_row(*head), _row(*("---",) * len(head)), *(_row(*r) for r in rows)])


def _envelope_plan() -> list[tuple[str, Any]]:
    """(field, check) of the stamped envelope fields, as every kind's plan begins."""
    cls = next(iter(MESSAGE_CLASSES.values()))
    env = set(_ENVELOPE_KEYS)
    return [(name, check) for name, _, check in cls._PLAN if name in env]


def envelope_table() -> str:
    kinds = ", ".join(f"`{k}`" for k in MESSAGE_CLASSES)
    rows = [("`v`", "int", f"{SCHEMA_VERSION}", "", ENVELOPE_NOTES["v"][1]),
            ("`kind`", "str", f"one of {kinds}", "", ENVELOPE_NOTES["kind"][1])]
    for name, check in _envelope_plan():
        unit, note = ENVELOPE_NOTES.get(name, ("", NO_NOTE))
        rows.append((f"`{name}`", *describe(check), unit, note))
    assert [r[0].strip("`") for r in rows] == list(_ENVELOPE_KEYS), "the envelope keys changed"
    return _table(("key", "type", "values", "unit", "meaning"), rows)


def key_of(kind: str) -> str:
    """The key a kind is published on, after ``truav/<run>/``."""
    place = MESSAGE_CLASSES[kind].PLACE
    if kind == schema_names.KIND_QSHARE:  # one key per part of a share
        return f"{keys.UAV}/<i>/{keys.QSHARE}/<n>"
    if kind == schema_names.KIND_OVERRIDE:  # one key per UAV
        return f"{keys.CONTROL_ROOT}/{keys.OVERRIDE}/<i>"
    if place[0] == keys.UAV:
        return f"{keys.UAV}/<i>/{'/'.join(place[1:])}"
    if len(place) == 1:
        return f"{place[0]}/{KEY_TAILS.get(place[0], '...')}"
    return "/".join(place)


def keys_table() -> str:
    rows = []
    for kind in MESSAGE_CLASSES:
        sender, to = SENDERS.get(kind, (NO_NOTE, ""))
        rows.append((f"`{key_of(kind)}`", f"`{kind}`", sender, to))
        if kind == schema_names.KIND_BEACON:
            rows.append((f"`{key_of(kind)}/<cx>_<cy>`", f"`{kind}`", sender,
                         f"agents near map cell (cx, cy), each in [0, {keys.MAX_CELLS}) (range-limited beacons)"))
    rows += [("`alive/world`", "liveliness token", "world", ""),
             ("`alive/uav/<i>`", "liveliness token", "uav/i", "world, agents, supervisor"),
             ("`alive/recorder`", "liveliness token", "recorder", ""),
             ("`alive/controller`", "liveliness token", "controller", "world (scheme central)")]
    return _table(("key after truav/<run>/", "payload", "sender (src)", "listeners"), rows)


def messages_tables() -> str:
    parts = []
    for kind, cls in MESSAGE_CLASSES.items():
        notes = FIELD_NOTES.get(kind, {})
        doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split()).replace("``", "`")
        rows = []
        for name, check in cls.CHECKS.items():
            unit, note = notes.get(name, ("", NO_NOTE))
            rows.append((f"`{name}`", *describe(check), unit, note))
        parts.append(f"#### `{kind}` on `{key_of(kind)}`\n\n{doc}\n\n"
                     + _table(("field", "type", "values", "unit", "meaning"), rows))
    return "\n\n".join(parts)


def limits_table() -> str:
    rows = []
    for kind in MESSAGE_CLASSES:
        lim = unpack_limits(kind)
        rows.append((f"`{kind}`", str(size_limit(kind)), str(lim["max_map_len"]), str(lim["max_array_len"]),
                     str(lim["max_str_len"]), str(lim["max_bin_len"]), str(lim["max_ext_len"])))
    return _table(("kind", "max bytes", "max map len", "max array len", "max str len", "max bin len",
                   "max ext len"), rows)


def reason_codes() -> list[str]:
    """Every reason a refused message is counted under: the schema's, the key check's, the guard's."""
    found = [getattr(schema_names, n) for n in vars(schema_names) if n.startswith("R_")]
    found.append(KEY_MISMATCH)
    found += [getattr(guard, n) for n in vars(guard) if n.startswith("R_")]
    return list(dict.fromkeys(found))


def reasons_table() -> str:
    return _table(("reason", "meaning"), [(f"`{r}`", REASON_NOTES.get(r, NO_NOTE)) for r in reason_codes()])


def actions_table() -> str:
    rows = []
    for a in [*range(N_ACTIONS), HOVER]:
        vx, vy = (round(float(x), 4) + 0.0 for x in ACTION_UNIT_VELOCITY[a])  # + 0.0: no -0
        frac = math.hypot(vx, vy)
        heading = "-" if frac == 0 else f"{math.degrees(math.atan2(vy, vx)) % 360:g}"
        rows.append((str(a), heading, f"{frac:g}", f"({vx:+.4f}, {vy:+.4f})"))
    return _table(("action", "heading (deg, counterclockwise from east = +x)", "speed (x speed_max)",
                   "velocity / speed_max (vx, vy)"), rows)


def constants_table() -> str:
    rows = [
        ("MAX_UAVS", str(keys.MAX_UAVS), "UAV ids are in [0, MAX_UAVS)"),
        ("MAX_SRC_LEN", str(schema_names.MAX_SRC_LEN), "characters of `src`"),
        ("MAX_NAME_LEN", str(schema_names.MAX_NAME_LEN), "characters of a metric, parameter, fault or command name"),
        ("BEACON_MAX_BYTES", str(schema_names.BEACON_MAX_BYTES), "the largest stamped beacon (bytes)"),
        ("TICK_WINDOW", str(guard.TICK_WINDOW), "a message's tick must be this close to the receiver's"),
        ("TICK_RESYNC_S", f"{guard.TICK_RESYNC_S:g}", "after this long without a tick, a world tick ahead of the "
                                                      "window moves it"),
        ("AREA_MARGIN_M", f"{guard.AREA_MARGIN_M:g}", "positions may lie this far outside the area (m)"),
        ("SPEED_MARGIN", f"{guard.SPEED_MARGIN:g}", "speeds may exceed the UAV's by this factor"),
        ("HEALTH_PERIOD_S", f"{HEALTH_PERIOD_S:g}", "an agent's health report period (s)"),
        ("REJECTION_PERIOD_S", f"{REJECTION_PERIOD_S:g}", "the world sends a UAV at most one rejection this "
                                                          "often (s)"),
        ("DEFAULT_LOCKSTEP_WAIT_S", f"{DEFAULT_LOCKSTEP_WAIT_S:g}", "lock-step: how long the world waits for a "
                                                                    "live agent's answer, an agent for a peer's beacon (s)"),
        ("MAX_QSHARE_ROWS", str(schema_names.MAX_QSHARE_ROWS), "Q rows in one qshare message (a share of more "
                                                               "rows is split over parts)"),
        ("MAX_QSHARE_PARTS", str(schema_names.MAX_QSHARE_PARTS), "parts one share may be split over"),
        ("LOCKSTEP_JOIN_GRACE_S", f"{LOCKSTEP_JOIN_GRACE_S:g}", "lock-step: how long an agent waits for a peer "
                                                                "not heard from since it joined (s); past 100 UAVs "
                                                                "times n_uavs / 100 (a round of 1,000 takes seconds)"),
    ]
    return _table(("name", "value", "meaning"), rows)


SECTIONS = {
    "envelope": envelope_table,
    "keys": keys_table,
    "messages": messages_tables,
    "limits": limits_table,
    "reasons": reasons_table,
    "actions": actions_table,
    "constants": constants_table,
}


def sections() -> dict[str, str]:
    """Every generated table by its marker name."""
    return {name: build() for name, build in SECTIONS.items()}


def _marker_re(name: str) -> re.Pattern[str]:
    return re.compile(rf"(<!-- generated: {re.escape(name)} -->\n)(.*?)(<!-- end generated: {re.escape(name)} -->)",
                      re.S)


def generated_parts(doc: str) -> dict[str, str | None]:
    """What ``doc`` holds between each section's markers (None: the markers are missing)."""
    out: dict[str, str | None] = {}
    for name in SECTIONS:
        m = _marker_re(name).search(doc)
        out[name] = None if m is None else m.group(2).strip("\n")
    return out


def render_into(doc: str) -> str:
    """``doc`` with every generated section replaced by the current tables; ValueError if markers are missing."""
    for name, text in sections().items():
        pattern = _marker_re(name)
        if pattern.search(doc) is None:
            raise ValueError(f"no '<!-- generated: {name} -->' ... '<!-- end generated: {name} -->' markers")
        doc = pattern.sub(lambda m: f"{m.group(1)}\n{text}\n\n{m.group(3)}", doc, count=1)
    return doc


__all__ = ["FIELD_NOTES", "NO_NOTE", "SECTIONS", "describe", "generated_parts", "key_of",
           "reason_codes", "render_into", "sections"]
