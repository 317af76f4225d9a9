"""`truav report` and `truav log recover|check`: pictures and CSV from a recording, and the CLI's
one-line errors.  Recordings are synthesised with McapLog (no network)."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from matplotlib.image import imread

from recorder.mcap_log import McapLog
from recorder.report import AGENTS_FILE, MAP_FILE, METRICS_CSV_FILE, METRICS_FIG_FILE, load_recording, report
from truav.cli.main import main as truav_main
from tests.support.recordings import MS, N_UAVS, make_swarm_recording

MIN_PNG_PIXELS = 400 * 300


def png_ok(path: Path) -> None:
    image = imread(path)
    assert image.shape[0] * image.shape[1] >= MIN_PNG_PIXELS
    assert image[..., :3].std() > 0.05  # not a blank canvas


def test_report_writes_pictures_and_csv(tmp_path: Path) -> None:
    path = tmp_path / "swarm.mcap"
    counts = make_swarm_recording(path)
    out, lines = report(path)
    assert out == tmp_path / "swarm_report"
    for name in (MAP_FILE, METRICS_FIG_FILE, AGENTS_FILE):
        png_ok(out / name)
    text = "\n".join(lines)
    assert "4 UAVs (beacons)" in text and "2 faults" in text and "4 beaconing" in text
    with open(out / METRICS_CSV_FILE, newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == counts["metrics"]
    assert set(rows[0]) == {"time_s", "log_time_ns", "publish_time_ns", "src", "scope", "episode", "tick",
                            "coverage_pct", "delivered", "pdr", "reward"}
    assert rows[0]["scope"] == "step" and rows[0]["reward"] == "" and float(rows[0]["coverage_pct"]) == 40.0
    assert [r["scope"] for r in rows].count("episode") == 2
    times = [float(r["time_s"]) for r in rows]
    assert times == sorted(times)


def test_recording_is_read_into_tracks_faults_and_config(tmp_path: Path) -> None:
    path = tmp_path / "swarm.mcap"
    make_swarm_recording(path)
    rec = load_recording(path)
    assert rec.config is not None and rec.config.block_m == 250.0 and len(rec.config.rsus) == 4
    source, tracks = rec.tracks()
    assert source == "beacons" and sorted(tracks) == list(range(N_UAVS))
    assert len(tracks[2].xy) == 90  # the crashed UAV stopped beaconing
    spans = rec.fault_spans()
    assert [(s.fault, s.target, round(s.start_s, 1), s.end_s and round(s.end_s, 1)) for s in spans] == [
        ("loss", "uav/1", 3.0, 5.0), ("crash", "uav/2", 9.0, None)]
    lat = (tracks[3].log_ns[0] - tracks[3].pub_ns[0]) / MS
    assert lat == pytest.approx(4.0)


def test_report_without_config_or_beacons_and_unfinished(tmp_path: Path) -> None:
    path = tmp_path / "bare.mcap"
    make_swarm_recording(path, config=False, beacons=False, finish=False)
    out, lines = report(path, tmp_path / "out")
    text = "\n".join(lines)
    assert "unfinished file" in text and "(observations)" in text and "no config in the file" in text
    assert f"{AGENTS_FILE}: skipped, no beacons" in text
    png_ok(out / MAP_FILE)
    assert not (out / AGENTS_FILE).exists() and (out / METRICS_CSV_FILE).exists()


def test_empty_recording_still_reports(tmp_path: Path) -> None:
    McapLog(tmp_path / "empty.mcap").close()
    out, lines = report(tmp_path / "empty.mcap")
    assert sum("skipped" in line for line in lines) == 4  # map, metrics, agents, links
    assert (out / METRICS_CSV_FILE).read_text().startswith("time_s,log_time_ns")


def test_cli_report_and_log_check_refuse_a_file_without_messages(tmp_path: Path, capsys) -> None:
    """Issue 25: `truav report` wrote an empty metrics.csv and exited 0 on an empty recording."""
    path = tmp_path / "empty.mcap"
    with McapLog(path) as log:
        log.set_metadata("truav.recording", {"run": "r"})
    assert truav_main(["log", "check", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no bus messages" in err[0] and str(path) in err[0], err
    assert truav_main(["report", str(path), "--out", str(tmp_path / "rep")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"truav: error: {path}: no bus messages in the file; nothing to report"], err
    assert not (tmp_path / "rep").exists()


def test_cli_report_log_check_and_recover(tmp_path: Path, capsys) -> None:
    path = tmp_path / "swarm.mcap"
    make_swarm_recording(path, finish=False)
    assert truav_main(["log", "check", str(path)]) == 1  # unfinished: not a clean bill of health
    out, err = capsys.readouterr()
    assert "UNFINISHED" in out and "uav/2" in out and "`truav log recover`" in err
    fixed = tmp_path / "fixed.mcap"
    assert truav_main(["log", "recover", str(path), str(fixed)]) == 0
    assert "unfinished (writer died)" in capsys.readouterr().out
    assert truav_main(["log", "check", str(fixed)]) == 0
    assert ": finished" in capsys.readouterr().out
    assert truav_main(["report", str(fixed), "--out", str(tmp_path / "rep")]) == 0
    assert "map.png" in capsys.readouterr().out and (tmp_path / "rep" / MAP_FILE).exists()


@pytest.mark.parametrize("argv, message", [
    (["report", "{missing}"], "no such file"),
    (["report", "{text}"], "not an MCAP file"),
    (["log", "check", "{missing}"], "no such file"),
    (["log", "check", "{text}"], "not an MCAP file"),
    (["log", "recover", "{missing}", "{out}"], "no such file"),
    (["log", "recover", "{text}", "{out}"], "not an MCAP file"),
])
def test_cli_mistakes_are_one_line_errors(tmp_path: Path, capsys, argv: list[str], message: str) -> None:
    (tmp_path / "text.mcap").write_text("not an mcap")
    names = {"missing": tmp_path / "nope.mcap", "text": tmp_path / "text.mcap", "out": tmp_path / "out.mcap"}
    assert truav_main([a.format(**names) for a in argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith("truav: error:") and "Traceback" not in err
