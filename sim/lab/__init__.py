"""The emulated lab cell: a UR controller (dashboard 29999, script port 30003, RTDE 30004), the Robotiq URCap
socket (63352) and a control channel (29990) for tests, served at the wire so that `hardware/` runs unchanged
through the real ur_rtde, pyrealsense2 and gripper socket. `python -m sim.lab serve|run`; see `sim.lab.__main__`.

This module holds the one piece every server shares: `TcpServer`, a listening socket whose clients each get a
thread, with the faults a link can have (drop every client, refuse connections for a while).
"""

from __future__ import annotations

import logging
import socket
import threading
import time

log = logging.getLogger(__name__)


class TcpServer:
    """Listens on (host, port) and runs `serve_client(sock)` on a thread per client (subclasses implement it)."""

    def __init__(self, host: str, port: int) -> None:
        self.down_until = 0.0  # until this time.monotonic(), new connections are closed at once (a link down)
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._listener = socket.create_server((host, port))
        self.port = self._listener.getsockname()[1]
        threading.Thread(target=self._accept, name=f"accept-{self.port}", daemon=True).start()

    def serve_client(self, sock: socket.socket) -> None:
        """Talk to one client until it goes; the socket is closed afterwards."""
        raise NotImplementedError

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except OSError:
                return
            if time.monotonic() < self.down_until:
                sock.close()
                continue
            with self._lock:
                self._clients.append(sock)
            threading.Thread(target=self._run_client, args=(sock,), name=f"client-{self.port}", daemon=True).start()

    def _run_client(self, sock: socket.socket) -> None:
        try:
            self.serve_client(sock)
        except OSError as exc:
            log.debug("port %d client: %s", self.port, exc)
        finally:
            sock.close()
            with self._lock:
                if sock in self._clients:
                    self._clients.remove(sock)

    def drop_clients(self) -> int:
        """Close every client connection (a link drop); returns how many were closed."""
        with self._lock:
            clients = list(self._clients)
        for sock in clients:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        return len(clients)

    def close(self) -> None:
        """Stop listening and drop every client."""
        self._listener.close()
        self.drop_clients()
