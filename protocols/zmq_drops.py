"""Inbound ZeroMQ connections that libzmq dropped itself, told apart from peers that closed theirs.

libzmq refuses a frame over ``ZMQ_MAXMSGSIZE`` from its header: it closes the connection without
reading the rest and says nothing but ``EVENT_DISCONNECTED``, the same event a peer's own close
gives. :class:`DropWatch` tells the two apart by what is left on the TCP connection. A thread reads
the socket's monitor events; on ``EVENT_ACCEPTED`` it duplicates the connection's descriptor (so the
connection outlives libzmq's close of its own descriptor), and on ``EVENT_DISCONNECTED`` it peeks at
the duplicate without reading:

- end of stream (or a reset): the peer closed the connection, after libzmq had read every byte;
- bytes still unread, or none and no end of stream: the peer had not closed it and libzmq dropped
  it in the middle of a frame, which after a successful handshake means a frame over the size
  limit (or a frame header that breaks the framing, which only a hand-made sender produces).

Connections that failed their handshake (``EVENT_HANDSHAKE_FAILED_*``: not ZeroMQ at all) are left
out. The duplicate is closed at once after the peek. A connection that was accepted and dropped
before the thread handled its ``EVENT_ACCEPTED`` (its descriptor already closed: it lived for less
than the thread's reaction time, a few milliseconds on a busy process) cannot be peeked; it is
counted as dropped too (and in :attr:`unseen`): a genuine peer's connection lives as long as its
process, so only a sender that closes at once after its handshake is counted wrongly.
"""

from __future__ import annotations

import os
import socket as pysocket
import threading

import zmq
from zmq.utils.monitor import recv_monitor_message

__all__ = ["DropWatch"]

_FAILED = tuple(getattr(zmq, name) for name in ("EVENT_HANDSHAKE_FAILED_NO_DETAIL", "EVENT_HANDSHAKE_FAILED_PROTOCOL",
                                                "EVENT_HANDSHAKE_FAILED_AUTH") if hasattr(zmq, name))


def _dropped_by_receiver(dup: int) -> bool:
    """Whether the TCP connection on ``dup`` (a duplicate descriptor, closed here) still had unread bytes or no end of
    stream. A descriptor that is no socket (libzmq's was closed and its number reused before it was duplicated):
    the connection was gone before it could be looked at, counted as dropped (module docstring)."""
    try:
        sock = pysocket.socket(fileno=dup)
    except OSError:
        os.close(dup)
        return True
    try:
        sock.setblocking(False)
        try:
            return sock.recv(1, pysocket.MSG_PEEK) != b""
        except BlockingIOError:
            return True  # open, nothing pending: the peer had not closed it
        except OSError:
            return False  # reset: the peer went away
    finally:
        sock.close()


class DropWatch:
    """Count the inbound connections of a bound ``zmq`` socket that libzmq dropped mid-frame.

    Parameters
    ----------
    socket : zmq.Socket
        A bound socket (its monitor is started here and stopped by :meth:`stop`).

    Attributes
    ----------
    dropped : int
        Connections dropped by libzmq with a frame unread (a frame over ``MAXMSGSIZE``).
    unseen : int
        Of those, connections dropped before their descriptor could be duplicated (not peeked).
    """

    def __init__(self, socket: zmq.Socket):
        self._monitor = socket.get_monitor_socket()
        self._socket = socket
        self._lock = threading.Lock()
        self._fds: dict[int, int] = {}  # libzmq's descriptor -> our duplicate (-1: closed before we looked)
        self.dropped = 0
        self.unseen = 0
        self._thread = threading.Thread(target=self._run, name="zmq-drop-watch", daemon=True)
        self._thread.start()

    def take(self) -> int:
        """Connections dropped mid-frame since the last call."""
        with self._lock:
            n, self.dropped = self.dropped, 0
        return n

    def stop(self) -> None:
        """Stop the monitor and its thread; close every duplicate descriptor. Safe to call twice."""
        if self._monitor is None:
            return
        try:
            self._socket.disable_monitor()
        except zmq.ZMQError:
            pass
        self._thread.join(timeout=1.0)
        if self._thread.is_alive():  # never seen; the daemon thread ends with the context
            self._monitor = None
            return
        self._monitor.close(linger=0)
        self._monitor = None
        for dup in self._fds.values():
            if dup >= 0:
                os.close(dup)
        self._fds.clear()

    def _run(self) -> None:
        monitor = self._monitor
        failed = False  # libzmq reports a failed handshake just before that connection's EVENT_DISCONNECTED
        while True:
            try:
                event = recv_monitor_message(monitor)
            except zmq.ZMQError:
                return
            if event["event"] == zmq.EVENT_MONITOR_STOPPED:
                return
            try:
                failed = self._handle(event["event"], event["value"], failed)
            except OSError:  # a descriptor gone under us: that connection is not classified, the watch goes on
                failed = False

    def _handle(self, kind: int, fd: int, failed: bool) -> bool:
        """Act on one monitor event; return whether a failed handshake awaits its disconnection."""
        if kind == zmq.EVENT_ACCEPTED:
            old = self._fds.pop(fd, -1)
            if old >= 0:
                os.close(old)
            try:
                self._fds[fd] = os.dup(fd)
            except OSError:  # closed already
                self._fds[fd] = -1
        elif kind in _FAILED:
            return True
        elif kind == zmq.EVENT_DISCONNECTED:
            dup = self._fds.pop(fd, -1)
            if failed:  # not a ZeroMQ peer: refused by the handshake, not a frame
                if dup >= 0:
                    os.close(dup)
                return False
            if dup < 0 or _dropped_by_receiver(dup):
                with self._lock:
                    self.unseen += dup < 0
                    self.dropped += 1
            return False
        return failed
