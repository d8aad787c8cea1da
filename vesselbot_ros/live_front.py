"""The live view's listening socket: one port for clients of either name of the Foxglove WebSocket protocol.

The protocol is one protocol under two WebSocket subprotocol names: the
specification's ``foxglove.websocket.v1`` (offered by older Foxglove releases,
Lichtblick, and ``@foxglove/ws-protocol``'s ``FoxgloveClient`` by default) and
``foxglove.sdk.v1``, the only name the Foxglove SDK's server accepts (0.30; any
other offer gets HTTP 400).  :class:`SubprotocolFront` listens on the live
view's port, reads each client's opening handshake, and hands the connection
to the SDK's server (on a private loopback port) as is, except that an offer of
the old name alone is passed on as ``foxglove.sdk.v1`` and the server's answer
names the old one again (RFC 6455 requires the server to pick a name the client
offered).  After the handshake it relays bytes both ways unchanged: every
message, control frame and close is the SDK's.  A client offering neither name
gets HTTP 400 naming both.

The front listens before it returns, so the port it reports accepts connections
(``port`` 0: the kernel's choice, read back with :attr:`SubprotocolFront.port`).
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from typing import NamedTuple

__all__ = ["SDK_SUBPROTOCOL", "SPEC_SUBPROTOCOL", "SUBPROTOCOLS", "SubprotocolFront", "Handshake", "rewrite_request",
           "rewrite_response", "offered_subprotocols"]

#: The name the Foxglove SDK's server accepts.
SDK_SUBPROTOCOL = "foxglove.sdk.v1"
#: The protocol specification's name (older Foxglove releases, Lichtblick, ``@foxglove/ws-protocol``).
SPEC_SUBPROTOCOL = "foxglove.websocket.v1"
#: Both, in the order of preference.
SUBPROTOCOLS = (SDK_SUBPROTOCOL, SPEC_SUBPROTOCOL)
#: Largest HTTP head (request line and headers) read from either side (bytes).
HEAD_LIMIT = 64 * 1024
#: Bound on a handshake (wall s): a client that opens a socket and sends nothing is dropped.
HANDSHAKE_TIMEOUT_S = 10.0
#: Bytes per relayed read.
CHUNK = 256 * 1024
_PROTOCOL_HEADER = b"sec-websocket-protocol"


class Handshake(NamedTuple):
    """A client's opening handshake as passed on to the SDK's server.

    Attributes:
        head: The HTTP head to send to the SDK (ends with a blank line).
        answer_as: The subprotocol to name in the answer to the client instead of
            :data:`SDK_SUBPROTOCOL` (None: the SDK's answer as it is).
        refused: An HTTP response to send the client instead (None: pass on).
    """

    head: bytes
    answer_as: str | None
    refused: bytes | None


def _header_lines(head: bytes) -> list[bytes]:
    return head.split(b"\r\n")


def offered_subprotocols(head: bytes) -> list[str]:
    """The subprotocol names of every ``Sec-WebSocket-Protocol`` header of an HTTP head, in order."""
    out: list[str] = []
    for line in _header_lines(head)[1:]:
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == _PROTOCOL_HEADER:
            out += [v.strip() for v in value.decode("latin-1").split(",") if v.strip()]
    return out


def _bad_request(text: str) -> bytes:
    body = text.encode("utf-8")
    return (b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\n"
            + f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode("ascii") + body)


def rewrite_request(head: bytes) -> Handshake:
    """What to do with a client's opening handshake ``head`` (the bytes up to and with the blank line).

    An offer that includes :data:`SDK_SUBPROTOCOL` is passed on unchanged; an offer of
    :data:`SPEC_SUBPROTOCOL` without it is passed on as :data:`SDK_SUBPROTOCOL` (answered as
    the spec's name); anything else is refused with HTTP 400 naming both.
    """
    offered = offered_subprotocols(head)
    if SDK_SUBPROTOCOL in offered:
        return Handshake(head, None, None)
    if SPEC_SUBPROTOCOL in offered:
        lines = [ln for ln in _header_lines(head) if ln.partition(b":")[0].strip().lower() != _PROTOCOL_HEADER]
        # the head ends with two empty "lines" (the blank line): insert before them
        lines[-2:-2] = [b"Sec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode("ascii")]
        return Handshake(b"\r\n".join(lines), SPEC_SUBPROTOCOL, None)
    return Handshake(head, None, _bad_request(
        f"vesselbot live view: offer the WebSocket subprotocol {SDK_SUBPROTOCOL} or {SPEC_SUBPROTOCOL} "
        f"(the Foxglove WebSocket protocol); offered: {', '.join(offered) or 'none'}\n"))


def rewrite_response(head: bytes, answer_as: str | None) -> bytes:
    """The SDK's answer ``head`` with its ``Sec-WebSocket-Protocol`` naming ``answer_as`` (None: unchanged)."""
    if answer_as is None:
        return head
    lines = _header_lines(head)
    for i, line in enumerate(lines):
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == _PROTOCOL_HEADER and value.strip() == SDK_SUBPROTOCOL.encode("ascii"):
            lines[i] = name + b": " + answer_as.encode("ascii")
    return b"\r\n".join(lines)


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """Read an HTTP head from ``sock``: (head up to and with the blank line, the bytes read after it)."""
    buf = b""
    while True:
        end = buf.find(b"\r\n\r\n")
        if end >= 0:
            return buf[:end + 4], buf[end + 4:]
        if len(buf) > HEAD_LIMIT:
            raise ValueError(f"HTTP head longer than {HEAD_LIMIT} bytes")
        data = sock.recv(8192)
        if not data:
            raise ConnectionError("closed during the handshake")
        buf += data


class SubprotocolFront:
    """Listens on ``host:port`` and hands every connection to the SDK's server at ``127.0.0.1:backend_port``.

    Args:
        backend_port: The SDK server's port (loopback).
        host: Interface to listen on.
        port: TCP port (0: any free one; see :attr:`port`).

    Raises:
        OSError: the port cannot be bound (in use, or not allowed).
    """

    def __init__(self, backend_port: int, host: str = "127.0.0.1", port: int = 0) -> None:
        self._backend = ("127.0.0.1", int(backend_port))
        self._listener = socket.create_server((host, int(port)), backlog=64)
        self.port = int(self._listener.getsockname()[1])
        self._lock = threading.Lock()
        self._conns: set[socket.socket] = set()
        self._pumps: list[threading.Thread] = []
        self._closed = False
        self._acceptor = threading.Thread(target=self._accept, name="live-front", daemon=True)
        self._acceptor.start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self._listener.accept()
            except OSError:  # closed
                return
            threading.Thread(target=self._serve, args=(conn,), name="live-front-conn", daemon=True).start()

    def _track(self, *socks: socket.socket) -> bool:
        with self._lock:
            if self._closed:
                return False
            self._conns.update(socks)
            return True

    def _forget(self, *socks: socket.socket) -> None:
        with self._lock:
            for s in socks:
                self._conns.discard(s)
        for s in socks:
            s.close()

    def _serve(self, client: socket.socket) -> None:
        backend: socket.socket | None = None
        if not self._track(client):
            client.close()
            return
        try:
            client.settimeout(HANDSHAKE_TIMEOUT_S)
            head, rest = _read_head(client)
            hs = rewrite_request(head)
            if hs.refused is not None:
                client.sendall(hs.refused)
                self._forget(client)
                return
            backend = socket.create_connection(self._backend, timeout=HANDSHAKE_TIMEOUT_S)
            if not self._track(backend):
                raise ConnectionError("closed")
            backend.sendall(hs.head + rest)
            answer, rest = _read_head(backend)
            client.sendall(rewrite_response(answer, hs.answer_as) + rest)
            client.settimeout(None)
            backend.settimeout(None)
        except (OSError, ValueError):
            self._forget(client, *([backend] if backend is not None else []))
            return
        # ends of one connection: each direction closes its write side when its source ends
        done = threading.Semaphore(0)
        down = threading.Thread(target=self._pump, args=(backend, client, done), name="live-front-down", daemon=True)
        with self._lock:
            self._pumps = [t for t in self._pumps if t.is_alive()] + [down]
        down.start()
        self._pump(client, backend, done)
        done.acquire()
        done.acquire()
        self._forget(client, backend)

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket, done: threading.Semaphore) -> None:
        buf = bytearray(CHUNK)
        view = memoryview(buf)
        try:
            while True:
                n = src.recv_into(buf)
                if not n:
                    break
                dst.sendall(view[:n])
            dst.shutdown(socket.SHUT_WR)
        except OSError:  # a reset on either side: end both directions
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
        finally:
            done.release()

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop listening; let relayed connections end (the SDK server closes them), at most ``timeout_s``.

        Call after stopping the SDK's server, so its close frames reach the clients.  Idempotent.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            pumps = list(self._pumps)
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)
        self._listener.close()
        deadline = time.monotonic() + timeout_s
        for t in pumps:
            t.join(max(0.0, deadline - time.monotonic()))
        with self._lock:
            left = list(self._conns)
        for s in left:  # a client that never closed its side
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
