"""A localhost hub for LCM's ``tcpq://`` transport, so two processes exchange LCM messages over
127.0.0.1 only (no multicast, nothing on the network).

LCM's ``tcpq`` provider (in the C library that ``pydrake.lcm.DrakeLcm`` and the ``lcm`` package
use) sends every message to a central hub over TCP, which relays it to each connected client
that subscribed to a matching channel. LCM ships its hub only in Java (``lcm.lcm.TCPService``);
this is the same protocol in Python:

- handshake: the client sends ``MAGIC_CLIENT`` and its protocol version (big-endian uint32), the
  hub answers ``MAGIC_SERVER`` and its version;
- then the client sends ``SUBSCRIBE`` / ``UNSUBSCRIBE`` (uint32 type, uint32 length, channel
  regex) and ``PUBLISH`` (uint32 type, uint32 length, channel, uint32 length, payload);
- the hub forwards each ``PUBLISH`` unchanged to every client with a subscription whose regex
  matches the whole channel name (the publisher included, as LCM's UDP transport does).

``LcmTcpqHub(port=0)`` picks a free port (``hub.url`` is the ``tcpq://127.0.0.1:PORT`` to give
both processes). The hub binds to 127.0.0.1 only.

The hub must outlive its clients. When the hub goes away under a connected client, the LCM C
library closes the client's socket and then hands ``select()`` the file descriptor -1 on the
client's next ``HandleSubscriptions``, which aborts the client process ("bit out of range 0 -
FD_SETSIZE on fd_set"): a crash of the station, not a timeout its watchdog could handle.
``HubProcess(..., idle_exit_s=S, detach=True)`` therefore runs the hub in its own session,
where ``release()`` leaves it running, and the hub ends by itself ``S`` seconds after its last
client left (``--idle-exit``); ``pcvfe vehicle-bridge`` starts its hub that way.
"""

from __future__ import annotations

import re
import socket
import struct
import threading
import time

MAGIC_SERVER = 0x287617FA
MAGIC_CLIENT = 0x287617FB
PROTOCOL_VERSION = 0x0100
PUBLISH, SUBSCRIBE, UNSUBSCRIBE = 1, 2, 3
HOST = "127.0.0.1"


_QUICKACK = getattr(socket, "TCP_QUICKACK", None)


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    chunks = []
    while n:
        if _QUICKACK is not None:
            # The LCM C client writes each message in several small send() calls without
            # TCP_NODELAY; acknowledging at once keeps Nagle's algorithm from holding its tail
            # back for a delayed ACK (tens of ms per message). Linux resets the flag after
            # each receive, so it is set before every one.
            sock.setsockopt(socket.IPPROTO_TCP, _QUICKACK, 1)
        chunk = sock.recv(n)
        if not chunk:
            raise ConnectionError("client closed the connection")
        chunks.append(chunk)
        n -= len(chunk)
    return b"".join(chunks)


def _recv_u32(sock: socket.socket) -> int:
    return struct.unpack(">I", _recv_exact(sock, 4))[0]


class _Client:
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.lock = threading.Lock()
        self.subscriptions: dict[str, re.Pattern] = {}

    def wants(self, channel: str) -> bool:
        return any(p.fullmatch(channel) for p in list(self.subscriptions.values()))

    def send(self, frame: bytes) -> bool:
        try:
            with self.lock:
                self.sock.sendall(frame)
            return True
        except OSError:
            return False


class LcmTcpqHub:
    """The relay; ``start()`` serves in background threads, ``close()`` stops them."""

    def __init__(self, port: int = 0) -> None:
        self._server = socket.create_server((HOST, int(port)))
        self.port = self._server.getsockname()[1]
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._accept_thread: threading.Thread | None = None
        self.messages_relayed = 0
        self.clients_seen = 0
        self._idle_since = time.monotonic()

    @property
    def url(self) -> str:
        """The LCM URL of this hub."""
        return f"tcpq://{HOST}:{self.port}"

    def start(self) -> LcmTcpqHub:
        self._accept_thread = threading.Thread(target=self._accept, name="tcpq-hub", daemon=True)
        self._accept_thread.start()
        return self

    def __enter__(self) -> LcmTcpqHub:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._closed.set()
        try:
            # shutdown() wakes the accept() blocked in the accept thread; close() alone would
            # leave the socket listening until that call returned.
            self._server.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        try:
            self._server.close()
        except OSError:
            pass
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            try:
                client.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            client.sock.close()

    def wait_idle(self, idle_s: float, first_client_s: float) -> str:
        """Block until no client has been connected for ``idle_s`` seconds after the last one
        left, or none came within ``first_client_s``; returns which."""
        while not self._closed.is_set():
            time.sleep(min(0.1, idle_s))
            with self._lock:
                connected, idle_since = len(self._clients), self._idle_since
            quiet = time.monotonic() - idle_since
            if connected:
                continue
            if self.clients_seen and quiet > idle_s:
                return "idle"
            if not self.clients_seen and quiet > first_client_s:
                return "no client"
        return "closed"

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                sock, _ = self._server.accept()
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=self._serve, args=(sock,), daemon=True).start()

    def _serve(self, sock: socket.socket) -> None:
        client = _Client(sock)
        try:
            magic, _version = _recv_u32(sock), _recv_u32(sock)
            if magic != MAGIC_CLIENT:
                sock.close()
                return
            sock.sendall(struct.pack(">II", MAGIC_SERVER, PROTOCOL_VERSION))
            with self._lock:
                self._clients.append(client)
                self.clients_seen += 1
            while not self._closed.is_set():
                kind = _recv_u32(sock)
                channel = _recv_exact(sock, _recv_u32(sock)).decode("utf-8", "replace")
                if kind == SUBSCRIBE:
                    client.subscriptions[channel] = re.compile(channel)
                elif kind == UNSUBSCRIBE:
                    client.subscriptions.pop(channel, None)
                elif kind == PUBLISH:
                    data = _recv_exact(sock, _recv_u32(sock))
                    self._relay(channel, data)
                else:
                    break
        except (ConnectionError, OSError, re.error):
            pass
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)
                    self._idle_since = time.monotonic()
            try:
                sock.close()
            except OSError:
                pass

    def _relay(self, channel: str, data: bytes) -> None:
        name = channel.encode()
        frame = struct.pack(">II", PUBLISH, len(name)) + name + struct.pack(">I", len(data)) + data
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            if client.wants(channel):
                client.send(frame)
        self.messages_relayed += 1


class HubProcess:
    """The hub in a child process (``python -m pcvfe_drake.hardware.tcpq_hub``).

    A hub must not share a Python process with a ``DrakeLcm`` client: the LCM C library waits
    for the hub's answers while holding the GIL, so a hub thread in the same process could never
    answer. ``HubProcess(port=0)`` starts the child, waits (at most ``timeout_s``) until it
    listens, and ``close()`` ends it. With ``idle_exit_s`` the hub ends by itself that long after
    its last client left (or ``max(30, idle_exit_s)`` s without any client); with ``detach`` it
    runs in its own session (a Ctrl-C in the terminal does not reach it) and ``release()``
    leaves it running for the clients still connected.
    """

    def __init__(
        self,
        port: int = 0,
        timeout_s: float = 10.0,
        *,
        idle_exit_s: float | None = None,
        detach: bool = False,
    ) -> None:
        import subprocess
        import sys

        command = [sys.executable, "-m", "pcvfe_drake.hardware.tcpq_hub", "--port", str(int(port))]
        if idle_exit_s is not None:
            command += ["--idle-exit", str(float(idle_exit_s))]
        self._proc = subprocess.Popen(
            command, stdout=subprocess.PIPE, text=True, start_new_session=detach
        )
        line = _readline_with_timeout(self._proc, timeout_s)
        if not line.startswith("tcpq://"):
            self.close()
            raise RuntimeError(f"the LCM tcpq hub did not start (it said {line!r})")
        self.url = line.strip()
        self.port = int(self.url.rsplit(":", 1)[1])

    def __enter__(self) -> HubProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def pid(self) -> int:
        return self._proc.pid

    def wait(self, timeout_s: float) -> int | None:
        """The hub's exit status once it has ended within ``timeout_s`` (None: still running)."""
        import subprocess

        try:
            return self._proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def release(self) -> None:
        """Stop managing the hub without ending it (it must have ``idle_exit_s``, so it ends by
        itself once its clients are gone)."""
        if self._proc.stdout is not None:
            self._proc.stdout.close()

    def close(self) -> None:
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=5)
            except Exception:
                self._proc.kill()
                self._proc.wait(timeout=5)
        if self._proc.stdout is not None:
            self._proc.stdout.close()


def hub_listening(port: int, timeout_s: float = 0.5) -> bool:
    """Whether something accepts TCP connections on 127.0.0.1:``port`` (a hub left running by an
    earlier bridge for its clients)."""
    try:
        with socket.create_connection((HOST, int(port)), timeout=timeout_s) as sock:
            # Say nothing and hang up: the hub drops a connection without a handshake.
            sock.shutdown(socket.SHUT_RDWR)
        return True
    except OSError:
        return False


def _readline_with_timeout(proc, timeout_s: float) -> str:
    result: list[str] = []
    reader = threading.Thread(target=lambda: result.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout_s)
    return result[0] if result else ""


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description="LCM tcpq hub on 127.0.0.1")
    parser.add_argument("--port", type=int, default=7700, help="TCP port (0: a free one)")
    parser.add_argument(
        "--idle-exit",
        type=float,
        default=None,
        help="end this many seconds after the last client left (default: run until killed)",
    )
    args = parser.parse_args(argv)
    hub = LcmTcpqHub(args.port).start()
    print(hub.url, flush=True)
    try:
        if args.idle_exit is None:
            threading.Event().wait()
        else:
            hub.wait_idle(args.idle_exit, max(30.0, args.idle_exit))
    except KeyboardInterrupt:
        pass
    finally:
        hub.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
