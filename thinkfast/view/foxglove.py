"""Live view in Foxglove (``thinkfast-run --foxglove [HOST:]PORT``): the Foxglove SDK's
WebSocket server in the daemon, fed by the Rerun view's own scheduler
(:class:`~thinkfast.view.live.DaemonView`: references queued at detection time, steps of
one or two messages run between EGM replies only when their measured cost fits the time left in
the cycle) through :class:`~thinkfast.view.channels.ChannelPainter` instead of the Rerun
painter. So the scene is the Rerun view's: arm and shield (commanded and measured), the ball's
belief (mean, velocity, covariance ellipsoid), the crossing Gaussian on the plane, the plan (the
shield along the chosen motion, its goal and text), the goal grid, the joints and the status.

Channels (log time = the daemon's time of the sample [ns since the Unix epoch]; frame ``base``):
the MCAP export's ROS 2 topics with the same schemas and CDR bytes
(:data:`thinkfast.view.ros_topics.TOPICS`; ``/thinkfast/decisions`` carries ``motion``, ``value``,
``best_goal``), ``/thinkfast/scene`` (``foxglove.SceneUpdate``, the entities of
:data:`thinkfast.view.scene.ENTITY_IDS`) and ``/thinkfast/status`` (JSON, the status message,
twice a second). Needs the ``foxglove`` extra (``foxglove-sdk``; rosbags for the CDR);
imported only with the option. The same server and channels play flight records
(``thinkfast-sim replay --foxglove``, :mod:`thinkfast.view.foxglove_replay`).
"""

from __future__ import annotations

import threading

from thinkfast.errors import ConfigError
from thinkfast.link.egm_address import EgmAddressError, parse_hostport
from thinkfast.view.live import DaemonView

BACKLOG = 4096  # messages queued per client before a slow one is dropped (the SDK's policy)


def foxglove_address(text: str) -> tuple[str, int]:
    """``--foxglove`` ``[HOST:]PORT`` -> (host, port); the host defaults to 127.0.0.1 (loopback).

    Raises:
        ConfigError: not ``[HOST:]PORT`` (:func:`~thinkfast.link.egm_address.parse_hostport`).
    """
    try:
        return parse_hostport(text, "--foxglove", "127.0.0.1", "8765, 0.0.0.0:8766")
    except EgmAddressError as exc:
        raise ConfigError("--foxglove", None, str(exc).removeprefix("--foxglove: ")) from None


class FoxgloveSink:
    """The SDK's server and one channel per topic of
    :func:`~thinkfast.view.channels.channel_specs`; :meth:`emit` logs one message.

    Args:
        host, port: where the WebSocket server listens (port 0: any free one, see ``port``).
        name: the server's name, shown by Foxglove.
        status: serve the status channel (the daemon's; a record has no status messages).
        count: keep ``subscriptions`` (a :class:`Subscriptions`: how many clients' channel
            subscriptions are open) up to date; else it is None.
    """

    def __init__(self, host: str, port: int, name: str = "thinkfast-run", status: bool = True,
                 count: bool = False):  # fmt: skip
        try:
            import foxglove
        except ImportError:
            raise ConfigError("--foxglove", None, "needs foxglove-sdk: pip install "
                              "'thinkfast[foxglove]'") from None  # fmt: skip
        from thinkfast.view.channels import channel_specs

        self.subscriptions = Subscriptions() if count else None
        listener = None if self.subscriptions is None else self.subscriptions.listener()
        self.server = foxglove.start_server(
            name=name, host=host, port=port, message_backlog_size=BACKLOG,
            server_listener=listener,
        )  # fmt: skip
        self.channels = {
            topic: foxglove.Channel(
                topic, schema=foxglove.Schema(name=schema, encoding=enc, data=data),
                message_encoding=msg_enc,
            )
            for topic, (schema, enc, data, msg_enc) in channel_specs(status).items()
        }  # fmt: skip

    @property
    def port(self) -> int:
        return self.server.port

    def emit(self, t: float, topic: str, data: bytes) -> None:
        self.channels[topic].log(data, log_time=int(t * 1e9))

    def close(self) -> None:
        self.server.stop()


class Subscriptions:
    """The clients' open channel subscriptions, counted from the SDK's callbacks (its thread):
    ``open`` now, ``first`` set at the first one."""

    def __init__(self):
        self.open = 0
        self.first = threading.Event()
        self._lock = threading.Lock()

    def listener(self):
        """A foxglove-sdk server listener keeping the count (an unsubscription comes for each
        of a client's subscriptions when it disconnects)."""
        from foxglove.websocket import ServerListener

        subs = self

        class Listener(ServerListener):
            def on_subscribe(self, client, channel) -> None:
                with subs._lock:
                    subs.open += 1
                subs.first.set()

            def on_unsubscribe(self, client, channel) -> None:
                with subs._lock:
                    subs.open -= 1

        return Listener()


class FoxgloveView(DaemonView):
    """The daemon's Foxglove view (module doc): a :class:`DaemonView` drawing on channels.

    Args:
        host, port: where the WebSocket server listens (port 0: any free one, see ``port``).
        robot: the robot; tree_view: the runtime tree (plane, goal grid, crossings);
        cfg: the run configuration; joint_rate: joint samples per second at most [Hz].
    """

    def __init__(self, host: str, port: int, robot, tree_view, cfg, joint_rate: float = 50.0):
        from thinkfast.view.channels import ChannelPainter

        self.sink = FoxgloveSink(host, port)
        painter = ChannelPainter(self.sink.emit, robot, tree_view.plane_x, tree_view.goal_yz)
        super().__init__(painter, cfg, tree_view, joint_rate, plane=robot.placement)

    @property
    def port(self) -> int:
        return self.sink.port

    def close(self) -> None:
        """Log what is still queued, then stop the server."""
        super().close()
        self.sink.close()
