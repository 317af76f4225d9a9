"""The mirror channels of a recording: what Foxglove can show beside the msgpack bus channels.

* a JSON *mirror* channel ``/json/<key>`` (message encoding ``json``, a real
  JSON Schema) for the kinds :func:`recorder.schemas.mirror_builder` converts,
  because Foxglove cannot decode msgpack;
* Foxglove well-known-schema mirrors (``/foxglove/...``: 3D scene, frame
  transforms, one LocationFix per UAV, a Log), built by
  :class:`recorder.foxglove.FoxgloveMirror` (protobuf encoding, the SDK's own
  schemas).

Every mirror topic starts with "/" and no bus key does (:func:`is_mirror_topic`).
:class:`MirrorChannels` writes both kinds through a :class:`recorder.mcap_writer.McapWriter`,
best effort: a body whose fields do not fit a mirror is only counted.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

from recorder.foxglove import MESSAGE_ENCODING as FOXGLOVE_ENCODING
from recorder.foxglove import FoxgloveMirror, Out
from recorder.mcap_writer import JSON_ENCODING, McapWriter
from recorder.schemas import MIRROR_SCHEMA_PREFIX, mirror_schema

__all__ = ["MirrorChannels", "KeyChannel", "MIRROR_PREFIX", "META_KIND", "META_MIRROR_OF", "is_mirror_topic"]

# --- naming constants (readers rely on these) --------------------------------------
MIRROR_PREFIX = "/json/"  # mirror topic = MIRROR_PREFIX + key; bus keys never start with "/"
META_KIND = "truav.kind"  # channel metadata: kind the schema was chosen for
META_MIRROR_OF = "truav.mirror_of"  # channel metadata on mirrors: the mirrored key


def is_mirror_topic(topic: str) -> bool:
    """JSON and Foxglove mirrors start with "/"; bus keys never do."""
    return topic.startswith("/")


_U32 = 0xFFFFFFFF


@dataclass(slots=True)
class KeyChannel:
    """Per-key channel state looked up once per message."""

    id: int
    kind: str
    mirror: Optional[Callable[[dict], bytes]]
    mirror_id: int = 0  # 0: mirror channel not created yet
    count: int = 0


class MirrorChannels:
    """Writes the JSON and Foxglove mirrors of bus messages; counts what it wrote and what did not fit.

    ``fox`` None: no Foxglove scene (the JSON mirrors depend on the channels' builders).
    """

    def __init__(self, writer: McapWriter, fox: Optional[FoxgloveMirror]) -> None:
        self._writer = writer
        self._append = writer.append
        self.fox = fox
        self.fox_kinds = fox.KINDS if fox is not None else frozenset()
        self._fox_chans: dict[str, list[int]] = {}  # topic -> [channel id, sequence]
        self.messages = 0  # mirror messages written
        self.errors = 0  # decodable, but the kind's fields did not fit the mirror

    def write_json(self, key: str, chan: KeyChannel, body: dict, log_time: int, pub: int, seq: int) -> None:
        """Best effort: a body whose fields do not fit the mirror is only counted."""
        try:
            data = chan.mirror(body)  # type: ignore[misc]
        except Exception:  # KeyError, TypeError, ValueError, IndexError from odd bodies
            self.errors += 1
            return
        if chan.mirror_id == 0:
            writer = self._writer
            sid = writer.json_schema_id(MIRROR_SCHEMA_PREFIX + chan.kind, mirror_schema(chan.kind))
            chan.mirror_id = writer.add_channel(MIRROR_PREFIX + key, JSON_ENCODING, sid,
                                                {META_KIND: chan.kind, META_MIRROR_OF: key})
        self.messages += 1
        self._append(chan.mirror_id, seq, log_time, pub, data)

    def feed_foxglove(self, kind: str, body: dict, log_time_ns: int, pub: int) -> None:
        """The Foxglove scene's messages for one bus message (odd bodies: counted, as for the JSON mirrors)."""
        try:
            outs = self.fox.feed(kind, body, log_time_ns)  # type: ignore[union-attr]
        except Exception:  # odd bodies: counted, as for the JSON mirrors
            self.errors += 1
        else:
            for out in outs:
                self.write_foxglove(out, log_time_ns, pub)

    def joined(self, src: str, log_time_ns: int, pub: int) -> None:
        """Log a sender's first message to Foxglove."""
        self.write_foxglove(self.fox.joined(src, log_time_ns), log_time_ns, pub)  # type: ignore[union-attr]

    def lost(self, src: str, kind: str, skipped: int, log_time_ns: int, pub: int) -> None:
        """Log a sequence gap to Foxglove."""
        self.write_foxglove(self.fox.lost(src, kind, skipped, log_time_ns), log_time_ns, pub)  # type: ignore[union-attr]

    def write_foxglove(self, out: Out, log_time_ns: int, publish_time_ns: Optional[int] = None) -> None:
        """Record one Foxglove mirror message (channel and schema made on first use)."""
        entry = self._fox_chans.get(out.topic)
        if entry is None:
            writer = self._writer
            sid = writer.add_schema(out.schema.name, out.schema.encoding, out.schema.data)
            entry = self._fox_chans[out.topic] = [
                writer.add_channel(out.topic, FOXGLOVE_ENCODING, sid, {META_KIND: "foxglove"}), 0]
        self._append(entry[0], entry[1] & _U32, log_time_ns,
                     log_time_ns if publish_time_ns is None else publish_time_ns, out.data)
        entry[1] += 1
        self.messages += 1
