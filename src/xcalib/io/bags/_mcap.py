"""MCAP files of either ROS profile, read with the ``mcap`` library and decoded with a rosbags
typestore: ``ros2`` (CDR) and ``ros1`` (what ``mcap convert`` makes of a ROS 1 bag) profiles,
schema names with or without ``/msg/`` (``sensor_msgs/Image`` as the official mcap ROS 2
examples write it, ``sensor_msgs/msg/Image`` as rosbag2 does). The reader offers the part of
rosbags' ``AnyReader`` interface that :mod:`.reader` uses (``connections``, ``messages``,
``deserialize``, ``typestore``, ``close``)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from ...errors import FormatError

__all__ = ["McapReader", "normalise_msgtype", "open_mcap"]

log = logging.getLogger(__name__)
_ENCODINGS = {"cdr": 2, "ros1": 1}


def normalise_msgtype(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (``pkg/msg/Type``, ``pkg/srv/...`` unchanged)."""
    parts = name.strip("/").split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else "/".join(parts)


@dataclass(frozen=True)
class McapConnection:
    id: int
    topic: str
    msgtype: str
    ros: int  # 1: ROS 1 serialisation, 2: CDR


class McapReader:
    """An opened MCAP file; ``store_for(ros)`` (a stock typestore of ROS 1 or 2) fills in the types
    its schemas do not define."""

    def __init__(self, path: Path, store_for):
        from mcap.reader import make_reader
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.path = Path(path)
        self._file = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        try:
            self._reader = make_reader(self._file)
            try:
                summary = self._reader.get_summary()
            except Exception:  # noqa: BLE001 - no footer: a recording that was not closed
                summary = None
            self._linear = summary is None
            schemas, channels = (summary.schemas, summary.channels) if summary is not None else self._scan()
            self.typestore = get_typestore(Stores.EMPTY)
            cons = []
            for ch in channels.values():
                schema = schemas.get(ch.schema_id)
                if ch.message_encoding not in _ENCODINGS or schema is None:
                    continue  # JSON, protobuf, ...: not ROS messages; not listed
                name = normalise_msgtype(schema.name)
                cons.append(McapConnection(ch.id, ch.topic, name, _ENCODINGS[ch.message_encoding]))
                if schema.encoding in ("ros2msg", "ros1msg") and schema.data and name not in self.typestore.fielddefs:
                    try:
                        self.typestore.register(get_types_from_msg(schema.data.decode(), name))
                    except Exception:  # noqa: BLE001 - a definition that does not parse: the stock one is used
                        pass
            self.connections = cons
        except Exception:
            self._file.close()
            raise
        ros1 = bool(self.connections) and all(c.ros == 1 for c in self.connections)
        default = store_for(1 if ros1 else 2)
        missing = {k: v for k, v in default.fielddefs.items() if k not in self.typestore.fielddefs}
        if missing:
            self.typestore.register(missing)
        self._ros = {c.msgtype: c.ros for c in self.connections}

    def _scan(self) -> tuple[dict, dict]:
        """Schemas and channels of a file without a summary section (a recording that was not
        closed), read from the records themselves."""
        from mcap.records import Channel, Schema
        from mcap.stream_reader import StreamReader

        from mcap.exceptions import EndOfFile

        schemas, channels = {}, {}
        self._file.seek(0)
        try:
            for rec in StreamReader(self._file, skip_magic=False).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
        except EndOfFile:  # the file ends without a footer: what was written is read
            log.warning("%s: the MCAP file ends without a summary and footer (a recording that was not "
                        "closed); reading the records it holds", self.path)
        self._file.seek(0)
        return schemas, channels

    def messages(self, connections=None, start: int | None = None, stop: int | None = None):
        """``(connection, log time ns, raw bytes)`` of ``connections`` (default: all), in log-time
        order; ``start`` / ``stop``: log times in ns (``start <= t < stop``), as rosbags takes them."""
        wanted = {c.id: c for c in (self.connections if connections is None else connections)}
        if not wanted:
            return
        topics = sorted({c.topic for c in wanted.values()})
        if self._linear:  # no summary to seek with: read the records in file order
            from mcap.reader import NonSeekingReader

            self._file.seek(0)
            it = NonSeekingReader(self._file).iter_messages(topics=topics, log_time_order=False)
        else:
            it = self._reader.iter_messages(topics=topics, log_time_order=True, starting_at=start, ending_before=stop)
        from mcap.exceptions import EndOfFile

        try:
            for _schema, channel, message in it:
                con = wanted.get(channel.id)
                t = int(message.log_time)
                if con is not None and (start is None or t >= start) and (stop is None or t < stop):
                    yield con, t, message.data
        except EndOfFile:
            if not self._linear:
                raise

    def deserialize(self, raw: bytes, msgtype: str):
        if self._ros.get(msgtype, 2) == 1:
            return self.typestore.deserialize_ros1(raw, msgtype)
        return self.typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        self._file.close()


def open_mcap(path: Path, store_for) -> McapReader:
    """An opened :class:`McapReader`; an unreadable file -> FormatError naming it."""
    try:
        return McapReader(path, store_for)
    except FileNotFoundError:
        raise
    except Exception as exc:  # noqa: BLE001 - the mcap library raises several types for corrupt files
        raise FormatError(path, f"not a readable MCAP file ({type(exc).__name__}: {exc})") from None
