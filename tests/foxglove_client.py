"""An independent Foxglove WebSocket client for the tests (``foxglove.sdk.v1`` subprotocol):
websocket-client for the connection, the protocol's JSON control messages (``advertise``,
``subscribe``) and binary ``messageData`` frames, protobuf classes built from a channel's
advertised FileDescriptorSet and CDR decoders built from its advertised ROS 2 message
definition. Nothing here imports foxglove-sdk or thinkfast: what it decodes, it decodes from
what the server advertised."""

from __future__ import annotations

import base64
import json
import struct
import time

import websocket
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

SUBPROTOCOL = "foxglove.sdk.v1"


def protobuf_class(channel: dict):
    """The message class of a protobuf channel from its advertised FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def ros2_decoder(channel: dict):
    """A CDR decoder built from the channel's advertised ROS 2 message definition alone (a
    fresh rosbags type store that knows no types but the advertised ones)."""
    from rosbags.typesys import Stores, get_typestore
    from rosbags.typesys.msg import get_types_from_msg

    assert channel["schemaEncoding"] == "ros2msg" and channel["encoding"] == "cdr"
    ts = get_typestore(Stores.EMPTY)
    name, text = channel["schemaName"], channel["schema"]
    types, parts = {}, text.split("=" * 80 + "\n")
    types.update(get_types_from_msg(parts[0], name))
    for part in parts[1:]:  # dependencies: "MSG: pkg/Type" then its definition
        head, _, body = part.partition("\n")
        dep = head.removeprefix("MSG: ").strip()
        types.update(get_types_from_msg(body, dep if "/msg/" in dep else dep.replace("/", "/msg/")))
    ts.register(types)
    return lambda data: ts.deserialize_cdr(data, name)


def connect(port: int, timeout: float = 10.0, alive=None):
    """A connection to ``ws://127.0.0.1:port``, retried until the server listens (``timeout``
    [s]; ``alive()`` false, e.g. the serving process exited, ends the wait at once)."""
    deadline = time.time() + timeout
    while True:
        try:
            return websocket.create_connection(
                f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], timeout=10
            )
        except (ConnectionRefusedError, websocket.WebSocketException):
            if time.time() > deadline or (alive is not None and not alive()):
                raise
            time.sleep(0.2)


def advertised(ws, n: int | None = None, want: str = "/thinkfast/scene") -> dict[str, dict]:
    """topic -> channel of the server's ``advertise`` messages: ``n`` channels, or (``n``
    None) until ``want`` is among them (10 s at most)."""
    channels: dict[str, dict] = {}
    deadline = time.time() + 10
    while time.time() < deadline:
        if (len(channels) >= n) if n is not None else want in channels:
            break
        msg = ws.recv()
        if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
            channels.update({c["topic"]: c for c in json.loads(msg)["channels"]})
    return channels


def listen(port: int, until, timeout: float, n_channels: int | None = 10, alive=None,
           arrivals: list | None = None):  # fmt: skip
    """Subscribe to every advertised channel (``n_channels`` of them; None: until the scene's
    is advertised); collect (log time [ns], payload) per topic until ``until(got)``,
    ``timeout`` [s] or the server closes the connection (a replay that ended). ``alive``: see
    :func:`connect`; ``arrivals``: gets the monotonic time [s] each message arrived.

    Returns:
        (topic -> advertised channel, topic -> [(log time, payload), ...] in arrival order).
    """
    ws = connect(port, timeout=timeout, alive=alive)
    channels = advertised(ws, n_channels)
    topics = sorted(channels)
    subs = [{"id": i, "channelId": channels[t]["id"]} for i, t in enumerate(topics)]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    got: dict[str, list] = {t: [] for t in topics}
    deadline = time.time() + timeout
    while time.time() < deadline and not until(got):
        try:
            data = ws.recv()
        except websocket.WebSocketTimeoutException:
            continue
        except (websocket.WebSocketConnectionClosedException, ConnectionError):
            break
        if not data:  # a close frame
            break
        if isinstance(data, bytes) and data[0] == 1:  # messageData: sub id, log time, payload
            sub, ts = struct.unpack_from("<IQ", data, 1)
            got[topics[sub]].append((ts, data[13:]))
            if arrivals is not None:
                arrivals.append(time.monotonic())
    ws.close()
    return channels, got
