"""A process's last words reach its peers: :func:`swarm.net.transport.wait_sent` waits for a
real TCP peer that is behind, and the recorder stops only once the run is over and quiet."""

from __future__ import annotations

import socket
import threading

from swarm.net import transport as tp
from swarm.runs.record import TAIL_S, EndOfRun


def _pair() -> tuple[socket.socket, socket.socket, socket.socket]:
    server = socket.create_server(("127.0.0.1", 0))
    sender = socket.create_connection(server.getsockname())
    receiver, _ = server.accept()
    return server, sender, receiver


def test_bytes_a_peer_has_not_taken_are_counted_until_it_reads_them():
    server, sender, receiver = _pair()
    try:
        sender.setblocking(False)
        sent = 0
        try:  # fill the peer's window and this side's buffer: the peer is stopped
            while sent < 1 << 24:
                sent += sender.send(b"x" * 65536)
        except BlockingIOError:
            pass
        peer = "{}:{}".format(*sender.getpeername())
        left = tp.unsent_bytes()
        assert left.get(peer, 0) > 0, left
        assert tp.wait_sent(timeout_s=0.2).get(peer, 0) > 0  # it gives up, and says what is left

        got = 0

        def read() -> None:
            nonlocal got
            while got < sent:
                got += len(receiver.recv(1 << 20))

        reader = threading.Thread(target=read)
        reader.start()  # the peer wakes up and reads
        assert peer not in tp.wait_sent(timeout_s=20.0)
        reader.join(20.0)
        assert got == sent
    finally:
        for s in (sender, receiver, server):
            s.close()


def test_the_recorder_stops_after_the_done_world_the_gone_agents_and_a_quiet_tail():
    end = EndOfRun({"cf1", "cf2"}, linger_s=0.0)
    for name in ("world", "cf1", "cf2", "recorder"):
        end.liveliness(name, True, 0.0)
    assert not end.over(done=True, got=5, now=1.0)  # done, but the agents are still there
    end.liveliness("world", False, 1.1)
    end.liveliness("cf1", False, 1.2)
    assert not end.over(done=True, got=0, now=1.3)  # cf2 may still have commands on the way
    end.liveliness("cf2", False, 1.4)
    assert not end.over(done=True, got=3, now=1.5)  # its last commands arrive
    assert not end.over(done=True, got=0, now=1.5 + 0.02)
    assert end.over(done=True, got=0, now=1.52 + TAIL_S)  # quiet for TAIL_S


def test_an_agent_that_never_goes_holds_the_recorder_only_so_long():
    end = EndOfRun({"cf1"}, linger_s=2.0)
    end.liveliness("cf1", True, 0.0)
    assert not end.over(done=True, got=0, now=10.0)  # done at 10 s: real drones land until 12 s
    assert not end.over(done=False, got=0, now=12.0 + tp.SEND_DRAIN_S - 0.1)
    assert end.over(done=False, got=0, now=12.0 + tp.SEND_DRAIN_S + 0.1)
