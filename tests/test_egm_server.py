"""EGM server over real UDP on 127.0.0.1 with real protobuf bytes."""

import socket
import threading
import time

import numpy as np
import pytest

from thinkfast.contract import egm
from thinkfast.link.egm_address import EgmAddressError
from thinkfast.link.egm_server import EgmServer

LOOPBACK = "127.0.0.1"


def _hold(fb, before=None):
    """Setpoint source for tests: hold the measured position, 0.1 rad/s on joint 1."""
    return fb.q_rad, np.array([0.1, 0, 0, 0, 0, 0])


@pytest.fixture
def client():
    socks = []

    def make():
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((LOOPBACK, 0))
        s.settimeout(1.0)
        socks.append(s)
        return s

    yield make
    for s in socks:
        s.close()


def _poll_until(server, n_received, timeout=2.0):
    t_end = time.monotonic() + timeout
    while server.counters.received < n_received and time.monotonic() < t_end:
        server.poll()
        if server.counters.received < n_received:  # a datagram on loopback is there at once:
            time.sleep(0.0005)  # sleep only while one is still missing
    server.poll()


def test_bad_controller_and_busy_port_are_clear_errors():
    for bad in ("robot", "1.2.3.4:0", "1.2.3.4:x", "1.2.3.4:70000"):
        with pytest.raises(EgmAddressError, match="--egm-controller"):
            EgmServer("127.0.0.1:0", _hold, controller=bad)
    with EgmServer("127.0.0.1:0", _hold) as a:
        with pytest.raises(EgmAddressError, match="cannot bind"):
            EgmServer(a.address, _hold)


@pytest.mark.realtime
def test_one_reply_per_request_with_seqno_plus_one_to_the_one_peer(client):
    a = client()
    seen = []

    def reply(fb, before=None):
        seen.append(fb)
        return _hold(fb)

    with EgmServer(f"{LOOPBACK}:0", reply) as server:
        assert server.poll() == 0  # nothing pending: returns at once
        rng = np.random.default_rng(2)
        qs = rng.uniform(-1, 1, (20, 6))
        for i, q in enumerate(qs):
            a.sendto(egm.encode_robot(i + 1, 4 * i, q), server.address)
            _poll_until(server, i + 1)
        replies = [egm.decode_sensor(a.recv(65535)) for _ in range(20)]
        a.settimeout(0.05)
        with pytest.raises(TimeoutError):  # exactly one reply per request
            a.recv(65535)
        assert server.counters.replied == 20 and server.counters.received == 20
        assert server.peer == a.getsockname()
    assert [r.seqno for r in replies] == list(range(1, 21))
    for r, q in zip(replies, qs, strict=True):
        assert r.mtype == egm.MSGTYPE_CORRECTION
        np.testing.assert_allclose(r.q_rad, q, atol=1e-12)
        np.testing.assert_allclose(r.qd_rad_s, [0.1, 0, 0, 0, 0, 0], atol=1e-12)
    assert [fb.seqno for fb in seen] == list(range(1, 21))


def _no_reply(sock, wait=0.05):
    sock.settimeout(wait)
    with pytest.raises(TimeoutError):
        sock.recv(65535)


@pytest.mark.realtime
def test_a_second_sender_is_never_answered_and_counted_by_source(client):
    a, b = client(), client()
    with EgmServer(f"{LOOPBACK}:0", _hold, handover=10.0) as server:
        for i in range(10):
            a.sendto(egm.encode_robot(i, 4 * i, np.zeros(6)), server.address)
            b.sendto(egm.encode_robot(i, 4 * i, np.zeros(6)), server.address)
            _poll_until(server, 2 * i + 2)
        assert server.peer == a.getsockname()
        assert server.counters.replied == 10 and server.counters.foreign == 10
        assert server.foreign_sources == {"{}:{}".format(*b.getsockname()): 10}
        _no_reply(b)


@pytest.mark.realtime
def test_the_peer_is_handed_over_only_after_it_was_silent(client):
    a, b = client(), client()
    with EgmServer(f"{LOOPBACK}:0", _hold, handover=0.2) as server:
        a.sendto(egm.encode_robot(1, 0, np.zeros(6)), server.address)
        _poll_until(server, 1)
        b.sendto(egm.encode_robot(1, 0, np.zeros(6)), server.address)  # a still fresh
        _poll_until(server, 2)
        assert server.peer == a.getsockname() and server.counters.foreign == 1
        time.sleep(0.25)
        b.sendto(egm.encode_robot(2, 4, np.zeros(6)), server.address)  # a silent: b takes over
        _poll_until(server, 3)
        assert server.peer == b.getsockname() and server.counters.handovers == 2
        a.sendto(egm.encode_robot(2, 4, np.zeros(6)), server.address)
        _poll_until(server, 4)
        assert server.peer == b.getsockname() and server.counters.foreign == 2


@pytest.mark.realtime
def test_a_named_controller_port_is_the_only_one_served(client):
    a, b = client(), client()
    port = a.getsockname()[1]
    with EgmServer(f"{LOOPBACK}:0", _hold, controller=f"{LOOPBACK}:{port}") as server:
        b.sendto(egm.encode_robot(1, 0, np.zeros(6)), server.address)  # same IP, other port
        a.sendto(egm.encode_robot(1, 0, np.zeros(6)), server.address)
        _poll_until(server, 2)
        assert (server.counters.foreign, server.counters.replied) == (1, 1)
        egm.decode_sensor(a.recv(65535))
        _no_reply(b)
    with EgmServer(f"{LOOPBACK}:0", _hold, controller="127.0.0.2") as server:
        a.sendto(egm.encode_robot(1, 1, np.zeros(6)), server.address)
        _poll_until(server, 1)
        assert (server.counters.foreign, server.counters.replied) == (1, 0)


def _answers_with_before():
    """A setpoint source that notes ``(seqno, seqno of before)`` of each request it answers."""
    got = []

    def reply(fb, before=None):
        got.append((fb.seqno, before.seqno))
        return _hold(fb)

    return got, reply


@pytest.mark.realtime
def test_a_backlog_is_answered_once_with_the_newest_packet(client):
    a, flood = client(), client()
    flood.setblocking(False)
    got, reply = _answers_with_before()

    with EgmServer(f"{LOOPBACK}:0", reply, controller=LOOPBACK) as server:
        for i in range(5):
            a.sendto(egm.encode_robot(i + 1, 4 * i, np.zeros(6)), server.address)
        for _ in range(200):  # a flood from another port of the same host, garbage
            flood.sendto(b"\x00" * 64, server.address)
        a.sendto(egm.encode_robot(6, 20, np.zeros(6)), server.address)
        time.sleep(0.05)
        n = 0
        while server.counters.received < 206:
            n += server.poll()
        assert got == [(6, 5)] and n == 1  # the five older ones were out of date already
        assert server.counters.superseded == 5 and server.counters.foreign == 200
        egm.decode_sensor(a.recv(65535))
        _no_reply(a)


def test_malformed_packets_in_a_backlog_are_counted_malformed_not_superseded(client):
    """A backlog of the peer: three valid packets, a malformed one after each of the first two.
    The newest valid one is answered with the valid one before it (the malformed one between
    them skipped); the two older valid ones were superseded; the malformed ones are counted as
    malformed (loopback queues each datagram before sendto returns: one poll reads all five)."""
    a = client()
    got, reply = _answers_with_before()

    with EgmServer(f"{LOOPBACK}:0", reply, controller=LOOPBACK) as server:
        for i in range(3):
            a.sendto(egm.encode_robot(i + 1, 4 * i, np.zeros(6)), server.address)
            if i < 2:
                a.sendto(egm.encode_robot(9, 4 * i, np.zeros(6))[:30], server.address)
        assert server.poll() == 1
        k = server.counters
        assert (k.received, k.replied, k.superseded, k.malformed) == (5, 1, 2, 2)
        assert got == [(3, 2)]


def _fuzz_packets(rng, n):
    good = [egm.encode_robot(i, i, rng.uniform(-3, 3, 6)) for i in range(50)]
    out = []
    for _ in range(n):
        kind = int(rng.integers(6))
        if kind == 0:
            p = rng.bytes(int(rng.integers(0, 200)))
        elif kind == 1:
            g = good[int(rng.integers(len(good)))]
            p = g[: int(rng.integers(0, len(g)))]
        elif kind == 2:
            b = bytearray(good[int(rng.integers(len(good)))])
            for _ in range(int(rng.integers(1, 5))):
                b[int(rng.integers(len(b)))] = int(rng.integers(256))
            p = bytes(b)
        elif kind == 3:
            msg = egm.EgmRobot.FromString(good[0])
            del msg.feedBack.joints.joints[int(rng.integers(0, 6)) :]
            if rng.integers(2):
                msg.feedBack.joints.joints.extend([float("nan")] * 6)
            p = msg.SerializeToString()
        elif kind == 4:
            p = egm.encode_sensor(1, 1, np.zeros(6), np.zeros(6))  # wrong message type
        else:
            p = good[int(rng.integers(len(good)))]
        out.append(p)
    return out


@pytest.mark.realtime
def test_ten_thousand_fuzzed_packets_are_counted_and_never_crash(client):
    c = client()
    c.setblocking(False)
    rng = np.random.default_rng(3)
    packets = _fuzz_packets(rng, 10_000)
    valid = 0
    for p in packets:
        try:
            egm.decode_robot(p)
            valid += 1
        except egm.EgmDecodeError:
            pass
    with EgmServer(f"{LOOPBACK}:0", _hold) as server:
        for i, p in enumerate(packets):
            c.sendto(p, server.address)
            _poll_until(server, i + 1)
            if i % 100 == 0:
                while True:  # drain the replies so the client buffer never fills
                    try:
                        egm.decode_sensor(c.recv(65535))
                    except BlockingIOError:
                        break
        k = server.counters
    assert k.received == 10_000
    assert k.malformed == 10_000 - valid and k.replied == valid > 1000
    assert k.reply_errors == k.socket_errors == k.foreign == 0


@pytest.mark.realtime
def test_a_failing_setpoint_source_is_counted_and_the_next_request_served(client):
    c = client()
    answers = iter([RuntimeError("boom"), (np.full(6, np.nan), np.zeros(6)), (np.zeros(5), 0)])

    def reply(fb, before=None):
        a = next(answers, None)
        if a is None:
            return _hold(fb)
        if isinstance(a, Exception):
            raise a
        return a

    with EgmServer(f"{LOOPBACK}:0", reply) as server:
        for i in range(4):
            c.sendto(egm.encode_robot(i, i, np.zeros(6)), server.address)
            _poll_until(server, i + 1)
        assert server.counters.reply_errors == 3 and server.counters.replied == 1
        assert egm.decode_sensor(c.recv(65535)).seqno == 1  # no seqno spent on unsent replies


@pytest.mark.realtime
def test_a_deferred_request_sends_nothing_spends_no_seqno_and_is_counted(client):
    """``reply_fn`` returning None leaves the request unanswered by design (the daemon does so
    after a silence, to measure the velocity from the next packet)."""
    c = client()
    c.settimeout(0.2)
    calls = []

    def reply(fb, before=None):
        calls.append(fb.seqno)
        return None if len(calls) == 1 else _hold(fb)

    with EgmServer(f"{LOOPBACK}:0", reply) as server:
        c.sendto(egm.encode_robot(7, 100, np.zeros(6)), server.address)
        _poll_until(server, 1)
        with pytest.raises(TimeoutError):
            c.recv(65535)
        c.sendto(egm.encode_robot(8, 104, np.zeros(6)), server.address)
        _poll_until(server, 2)
        first = egm.decode_sensor(c.recv(65535))
        k = server.counters
        assert (k.deferred, k.replied, k.reply_errors) == (1, 1, 0)
        assert first.seqno == 1 and calls == [7, 8]


@pytest.mark.realtime
def test_serve_thread_replies_as_packets_arrive_and_stops_on_event(client):
    c = client()
    with EgmServer(f"{LOOPBACK}:0", _hold) as server:
        stop = threading.Event()
        th = threading.Thread(target=server.serve, args=(stop, 0.01))
        th.start()
        rtts = []
        for i in range(200):
            t0 = time.perf_counter()
            c.sendto(egm.encode_robot(i, i, np.zeros(6)), server.address)
            egm.decode_sensor(c.recv(65535))
            rtts.append(time.perf_counter() - t0)
        stop.set()
        th.join(1.0)
        assert not th.is_alive()
        assert server.counters.replied == 200
        assert server.last_rx_time is not None and server.peer == c.getsockname()
    assert len(rtts) == 200 and min(rtts) > 0.0  # latency figures: bench/egm_latency.py


@pytest.mark.parametrize("timing", [True, False], ids=["stamped", "unstamped"])
def test_a_request_that_arrived_before_the_last_reply_left_marks_that_reply_late(client, timing):
    """The controller sends its next request as its next cycle begins: one that was already in
    the socket when the last reply left means that reply came a cycle late (``behind``), with or
    without kernel arrival stamps; one sent after the reply arrived does not."""
    c = client()
    seen = []

    def reply(fb, before=None):
        seen.append(server.behind)
        if fb.seqno == 1:  # the next request arrives while this reply is being made
            c.sendto(egm.encode_robot(2, 4, np.zeros(6)), server.address)
        return _hold(fb)

    with EgmServer(f"{LOOPBACK}:0", reply, timing=timing) as server:
        c.sendto(egm.encode_robot(1, 0, np.zeros(6)), server.address)
        _poll_until(server, 1)
        _poll_until(server, 2)
        c.recv(65535), c.recv(65535)
        c.sendto(egm.encode_robot(3, 8, np.zeros(6)), server.address)  # after the reply
        _poll_until(server, 3)
    assert seen == [False, True, False] and server.counters.behind == 1


@pytest.mark.parametrize("waiting", ["stranger", "garbage", "duplicate"])
def test_only_the_peers_next_request_waiting_marks_the_reply_late(client, waiting):
    """A stranger's request, the peer's garbage or a duplicate of the request being answered,
    waiting in the socket as the reply leaves, say nothing of the controller's next cycle: the
    next reply is not marked late, and each is counted for what it is."""
    c, stranger = client(), client()
    seen = []
    extra = {
        "stranger": (stranger, egm.encode_robot(9, 4, np.zeros(6))),
        "garbage": (c, b"\x0a\x02junk"),
        "duplicate": (c, egm.encode_robot(1, 0, np.zeros(6))),
    }[waiting]

    def reply(fb, before=None):
        seen.append(server.behind)
        if fb.seqno == 1 and len(seen) == 1:
            extra[0].sendto(extra[1], server.address)
        return _hold(fb)

    with EgmServer(f"{LOOPBACK}:0", reply) as server:
        c.sendto(egm.encode_robot(1, 0, np.zeros(6)), server.address)
        _poll_until(server, 1)
        _poll_until(server, 2)
        c.sendto(egm.encode_robot(2, 4, np.zeros(6)), server.address)
        _poll_until(server, 3)
    assert server.counters.behind == 0 and not any(seen), seen
    counters = server.counters
    assert (counters.foreign, counters.malformed) == {
        "stranger": (1, 0),
        "garbage": (0, 1),
        "duplicate": (0, 0),
    }[waiting]
