"""rmw_zenoh's layout on a zenoh session: liveliness tokens, attachments, publishers, nodes.

What makes our zenoh entities ROS 2 entities to a node running ``rmw_zenoh_cpp`` (docs/ROS2.md;
the key expressions and the CDR payloads: :mod:`thinkfast.contract.ros`):

* **attachment** of every sample, 33 bytes in zenoh's own serialisation: sequence number (int64
  little endian, 1 for a publisher's first sample), source timestamp (int64 little endian, ns
  since the Unix epoch), and the publisher's 16-byte GID (one LEB128 length byte, 16, then the
  bytes); :func:`encode_attachment`;
* **liveliness tokens** ``@ros2_lv/...`` for the node and each publisher and subscription
  (:class:`RosNode`), so that ``ros2 node list`` / ``ros2 topic list`` / ``ros2 topic echo``
  find them.
"""

from __future__ import annotations

import hashlib
import struct
import time
from typing import NamedTuple

import zenoh

from thinkfast.contract.ros import (
    RosDecodeError,
    check_domain,
    dds_type_name,
    topic_key,
    type_hash,
)

GID_SIZE = 16  # RMW_GID_STORAGE_SIZE
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
# QoS part of a liveliness token (rmw_zenoh's compact form): the defaults (reliable, volatile,
# keep last) with depth 10, as rmw_zenoh writes it for a default profile of depth 10
QOS_TOKEN = "::,10:,:,:,,"


# ----------------------------------------------------------------------------- liveliness tokens
def _mangle(name: str) -> str:
    """A name inside a liveliness token: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def node_token(domain: int, zid: str, node_id: int, ns: str, node: str) -> str:
    """Liveliness key of a node (entity kind ``NN``; enclave unset)."""
    return f"@ros2_lv/{domain}/{zid}/{node_id}/{node_id}/NN/%/{_mangle(ns)}/{node}"


def entity_token(
    domain: int, zid: str, node_id: int, entity_id: int, kind: str, ns: str, node: str,
    topic: str, msgtype: str,
) -> str:  # fmt: skip
    """Liveliness key of a publisher (``kind`` ``MP``) or subscription (``MS``) of ``topic``."""
    return (
        f"@ros2_lv/{domain}/{zid}/{node_id}/{entity_id}/{kind}/%/{_mangle(ns)}/{node}/"
        f"{_mangle(topic)}/{dds_type_name(msgtype)}/{type_hash(msgtype)}/{QOS_TOKEN}"
    )


# ----------------------------------------------------------------------------- attachment
class Attachment(NamedTuple):
    """What rmw_zenoh attaches to a sample: ``seq`` (a publisher's counter, from 1), ``stamp_ns``
    (source time [ns since the Unix epoch]) and the publisher's ``gid`` (16 bytes)."""

    seq: int
    stamp_ns: int
    gid: bytes


def encode_attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment, written by zenoh's serialiser (``zenoh.ext.z_serialize``: two
    int64 little endian, then the GID as a sequence: LEB128 length 16 and the bytes)."""
    import zenoh.ext as zx

    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return zx.z_serialize((zx.Int64(seq), zx.Int64(stamp_ns), bytes(gid))).to_bytes()


def decode_attachment(data: bytes | None) -> Attachment:
    """Read an attachment written by :func:`encode_attachment` (or by rmw_zenoh).

    Raises:
        RosDecodeError: missing, or not 33 bytes of that layout.
    """
    if data is None:
        raise RosDecodeError("the sample has no attachment (rmw_zenoh always sends one)")
    data = bytes(data)
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        raise RosDecodeError(f"attachment of {len(data)} bytes is not rmw_zenoh's (33)")
    seq, stamp_ns = struct.unpack_from("<qq", data)
    return Attachment(seq, stamp_ns, data[17:])


def publisher_gid(token: str) -> bytes:
    """A stable 16-byte GID for the entity of liveliness key ``token`` (the first 16 bytes of its
    SHA-256; rmw_zenoh takes an XXH3-128 of the same key, the value only has to be unique)."""
    return hashlib.sha256(token.encode()).digest()[:GID_SIZE]


# ----------------------------------------------------------------------------- zenoh entities
class RosPublisher:
    """A ROS 2 publisher on a zenoh session: rmw_zenoh's key, attachment and liveliness token.

    Args:
        session: an open zenoh session.
        key: the topic's key expression (:func:`topic_key`).
        token: the publisher's liveliness key (:func:`entity_token`).
    """

    def __init__(self, session, key: str, token: str):
        self.key = key
        self.pub = session.declare_publisher(key)
        self.token = session.liveliness().declare_token(token)
        self.gid = publisher_gid(token)
        self.seq = 1

    def put(self, cdr: bytes) -> None:
        """Publish one CDR payload with the next sequence number and the time now."""
        self.pub.put(
            cdr,
            attachment=encode_attachment(self.seq, time.time_ns(), self.gid),
            source_info=zenoh.SourceInfo(self.pub.id, self.seq),  # a secured daemon's check
        )
        self.seq += 1

    def close(self) -> None:
        for e in (self.token, self.pub):
            try:
                e.undeclare()
            except Exception:  # already gone with the session
                pass


class RosNode:
    """A ROS 2 node made of zenoh entities: its liveliness token, and publishers and
    subscriptions declared with theirs (what ``ros2 node list`` / ``ros2 topic list`` read).

    Args:
        session: an open zenoh session (one node per session here).
        domain: ROS domain id.
        name: node name (``thinkfast_run``, ``thinkfast_detect``).
        ns: node namespace (``/`` for none).
    """

    def __init__(self, session, domain: int, name: str, ns: str = "/"):
        self.session, self.domain, self.name, self.ns = session, check_domain(domain), name, ns
        self.zid = str(session.info.zid())
        self.node_id = 0
        self._next_id = 1
        self.token = session.liveliness().declare_token(
            node_token(self.domain, self.zid, self.node_id, ns, name)
        )
        self._entities: list = []

    def _token(self, kind: str, topic: str, msgtype: str) -> str:
        eid, self._next_id = self._next_id, self._next_id + 1
        return entity_token(
            self.domain, self.zid, self.node_id, eid, kind, self.ns, self.name, topic, msgtype
        )

    def publisher(self, topic: str, msgtype: str) -> RosPublisher:
        """A publisher of ``msgtype`` on ``topic`` (fully qualified)."""
        pub = RosPublisher(
            self.session, topic_key(self.domain, topic, msgtype), self._token("MP", topic, msgtype)
        )
        self._entities.append(pub)
        return pub

    def subscriber(self, topic: str, msgtype: str, handler):
        """A zenoh subscriber of ``msgtype`` on ``topic`` with ``handler`` (a callback or a
        zenoh channel), announced as a ROS subscription."""
        sub = self.session.declare_subscriber(topic_key(self.domain, topic, msgtype), handler)
        token = self.session.liveliness().declare_token(self._token("MS", topic, msgtype))
        self._entities += [sub, token]
        return sub

    def close(self) -> None:
        """Undeclare every entity and the node's token (before the session closes)."""
        for e in [*self._entities, self.token]:
            try:
                e.close() if isinstance(e, RosPublisher) else e.undeclare()
            except Exception:
                pass
        self._entities.clear()
