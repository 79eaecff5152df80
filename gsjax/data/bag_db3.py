"""A ROS 2 sqlite3 bag file read without its ``metadata.yaml``: what the RealSense SDK (2.5x) writes as one ``.db3``
file. The file is the rosbag2 sqlite3 storage itself (tables ``topics`` and ``messages``, CDR payloads), so it is
read with SQL and deserialized with rosbags' ROS 2 type store; the interface is the part of
``rosbags.highlevel.AnyReader`` that :class:`gsjax.data.rosbag.BagFile` uses."""

from __future__ import annotations

import sqlite3
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Db3Connection:
    """A topic of the file: its row ``id``, ``topic`` name and ``msgtype``."""

    id: int
    topic: str
    msgtype: str


class Db3Reader:
    """Messages of a bare rosbag2 sqlite3 file; raises sqlite3 errors for a file that is not one."""

    def __init__(self, path: Path):
        from rosbags.typesys import Stores, get_typestore

        self._db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, check_same_thread=False)
        rows = self._db.execute("SELECT id, name, type FROM topics ORDER BY id").fetchall()
        self.connections = [Db3Connection(int(i), str(name), str(kind)) for i, name, kind in rows]
        self.message_count = int(self._db.execute("SELECT COUNT(*) FROM messages").fetchone()[0])
        self._types = get_typestore(Stores.ROS2_HUMBLE)

    def messages(self, connections: Collection[Db3Connection] = (), start: int | None = None,
                 stop: int | None = None) -> Iterator[tuple[Db3Connection, int, bytes]]:
        """(connection, timestamp ns, CDR bytes) of the messages on ``connections`` (all when empty) with
        ``start`` <= timestamp < ``stop``, in timestamp order."""
        by_id = {c.id: c for c in (connections or self.connections)}
        marks = ",".join("?" * len(by_id))
        query = f"SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({marks})"
        args: list[int] = list(by_id)
        if start is not None:
            query, args = query + " AND timestamp >= ?", [*args, start]
        if stop is not None:
            query, args = query + " AND timestamp < ?", [*args, stop]
        for topic_id, timestamp, data in self._db.execute(query + " ORDER BY timestamp, id", args):
            yield by_id[topic_id], int(timestamp), bytes(data)

    def deserialize(self, rawdata: bytes, msgtype: str) -> Any:
        return self._types.deserialize_cdr(rawdata, msgtype)
