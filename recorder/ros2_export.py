"""`truav log ros2bag`: a TRUAV recording as a ROS 2 bag (rosbag2, MCAP storage) for ``ros2 bag play`` and RViz.

The recording is read through the guarded reader (:func:`recorder.reader.iter_messages`: the file is
untrusted; damage raises :class:`recorder.mcap_guard.DamagedRecording`), every message mapped by
:class:`recorder.ros2_messages.Ros2Mapper` and serialized to CDR by rosbags' ROS 2 Jazzy typestore.

Written with ``rosbags.rosbag2.Writer`` in MCAP storage (rosbag2 format 9, Jazzy's): a bag directory,
``metadata.yaml`` beside ``<name>.mcap``, the layout ``ros2 bag info`` and ``ros2 bag play`` read natively
(with each topic's type, QoS profile and type hash), its MCAP file carrying ``ros2msg`` schemas and ``cdr``
messages that any MCAP reader (mcap-ros2-support, Foxglove) decodes too. The bag is built in
``OUT.part/`` and moved to OUT when complete, so a failed export leaves no half bag named OUT.
Message times in the bag are the recording's log times (as the header stamps).
"""

from __future__ import annotations

import shutil
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import msgpack

from recorder.foxglove import Geometry
from recorder.metadata import read_config_toml
from recorder.reader import iter_messages
from recorder.ros2_messages import Ros2Mapper

EXTRA_HINT = "pip install -e '.[ros2]'"


class Ros2Unavailable(RuntimeError):
    """rosbags is not installed (the ``ros2`` extra)."""


@dataclass
class ExportReport:
    out: Path
    messages: Counter = field(default_factory=Counter)  # per topic
    undecodable: int = 0  # payloads that are not a msgpack map: left out

    @property
    def total(self) -> int:
        return sum(self.messages.values())


def _geometry(recording: Path) -> Geometry:
    """The scenario's altitude and RSUs from the run's config metadata (the defaults when there is none or it is
    not a config: a file from elsewhere still exports, its z being the default altitude)."""
    text = read_config_toml(recording)  # DamagedRecording on a damaged file
    try:
        return Geometry.from_toml(text)
    except Exception:  # an old or foreign config: the defaults, as the report draws without roads
        return Geometry()


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (what --force may replace): a directory holding metadata.yaml."""
    return path.is_dir() and (path / "metadata.yaml").is_file()


def export(recording: Path, out: Path, replace: bool = False) -> ExportReport:
    """Write ``recording``'s poses, markers and metrics as the bag directory ``out``; an existing ``out`` (a bag
    or a file) is replaced once the new bag is complete when ``replace``, else must not exist.
    Raises Ros2Unavailable without rosbags, DamagedRecording on a damaged recording, OSError on a write error."""
    try:
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise Ros2Unavailable(f"needs rosbags (the ros2 extra): {EXTRA_HINT}") from None
    typestore = get_typestore(Stores.ROS2_JAZZY)
    mapper = Ros2Mapper(typestore, _geometry(recording))
    staging = out.parent / f"{out.name}.part"
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir()
    report = ExportReport(out)
    try:
        writer = Writer(staging / out.name, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with writer:
            connections: dict[str, object] = {}
            for key, payload, log_ns, _ in iter_messages(recording):
                try:
                    body = msgpack.unpackb(payload)
                except Exception:  # any msgpack failure: the message is left out, counted
                    report.undecodable += 1
                    continue
                if not isinstance(body, dict):
                    report.undecodable += 1
                    continue
                for topic, msgtype, message in mapper.feed(body.get("kind"), key, body, log_ns):
                    conn = connections.get(topic)
                    if conn is None:
                        conn = connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
                    writer.write(conn, log_ns, typestore.serialize_cdr(message, msgtype))
                    report.messages[topic] += 1
        if replace and is_bag(out):
            shutil.rmtree(out)
        elif replace and out.is_file():
            out.unlink()
        (staging / out.name).rename(out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return report
