"""`truav report`'s links.png: what each receiver heard, per link, from the agents' own counts (their health
reports' ``heard``), and the health report's ``heard`` on the wire (an older report without it still decodes)."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from recorder.report import LINKS_FILE, load_recording, report
from recorder.report_links import link_delivery
from tests.support.recordings import N_UAVS, make_swarm_recording
from truav.wire import schema


def _share(tmp_path, loss):
    path = tmp_path / f"loss{loss}.mcap"
    make_swarm_recording(path, heard_loss=loss)
    links = link_delivery(load_recording(path))
    assert links is not None and links.receivers.all()
    return links


def test_receiver_side_loss_shows_in_the_link_matrix(tmp_path) -> None:
    links = _share(tmp_path, 0.3)
    share = links.share
    off = ~np.eye(N_UAVS, dtype=bool)
    overall = links.heard[off].sum() / links.sent[off].sum()
    assert 0.64 < overall < 0.76, overall
    assert np.nanmax(share) < 0.9 and np.isnan(np.diag(share)).all()
    out, lines = report(tmp_path / "loss0.3.mcap", tmp_path / "rep")
    assert (out / LINKS_FILE).stat().st_size > 10_000
    assert any("links: 4 receivers, delivery" in line and "%" in line for line in lines), lines


def test_a_clean_run_delivers_every_beacon_even_to_a_receiver_that_crashed(tmp_path) -> None:
    share = _share(tmp_path, 0.0).share
    off = ~np.eye(N_UAVS, dtype=bool)
    assert (share[off] == 1.0).all(), share


def test_without_counts_the_links_figure_is_skipped_and_said(tmp_path) -> None:
    path = tmp_path / "old.mcap"
    make_swarm_recording(path)
    assert link_delivery(load_recording(path)) is None
    _, lines = report(path, tmp_path / "rep")
    assert f"  {LINKS_FILE}: skipped, no agent counted the beacons it heard in the recording" in lines


def _health(**extra):
    return schema.Health(uav=1, last_tick=3, steps=3, stale_obs_skipped=0, rejected={}, senders={}, **extra,
                         src="uav/1", seq=0, t=5, inc=9)


def test_heard_goes_over_the_wire_and_an_older_report_without_it_decodes() -> None:
    h = _health(heard=np.array([4, 0, 7]))
    assert h.heard == (4, 0, 7)
    assert schema.decode(schema.encode(h), "health") == h
    old = msgpack.unpackb(schema.encode(_health()))
    del old["heard"]
    assert schema.decode(msgpack.packb(old), "health").heard == ()
    del old["inc"]  # from before incarnations too
    assert schema.decode(msgpack.packb(old), "health").heard == ()


@pytest.mark.parametrize("heard, reason", [([1] * (schema.MAX_UAVS + 1), schema.R_OUT_OF_RANGE),
                                           ([1, -1], schema.R_OUT_OF_RANGE), ([1.5], schema.R_BAD_TYPE),
                                           ("abc", schema.R_BAD_TYPE)])
def test_heard_is_bounded_and_checked(heard, reason) -> None:
    wire = msgpack.unpackb(schema.encode(_health()))
    wire["heard"] = heard
    with pytest.raises(schema.SchemaError) as exc:
        schema.decode(msgpack.packb(wire), "health")
    assert exc.value.reason in (reason, schema.R_TOO_LARGE)
