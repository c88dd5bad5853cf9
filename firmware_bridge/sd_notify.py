"""systemd's notification protocol (sd_notify(3)): datagrams of ``KEY=VALUE`` lines to ``$NOTIFY_SOCKET``.

Written out (30 lines) rather than taken from the ``sdnotify`` package: that package (last release 2017)
swallows every socket error unless ``debug=True`` and reads the environment inside its constructor; here the
composition root passes the socket path in, and a failed send is counted and reported in the status.
"""

from __future__ import annotations

import socket

__all__ = ["SdNotify"]


class SdNotify:
    """``SdNotify(os.environ.get("NOTIFY_SOCKET"))``; with no socket (not under systemd) every call is a no-op."""

    def __init__(self, socket_path: str | None) -> None:
        self.enabled = bool(socket_path)
        self.failures = 0
        self._sock: socket.socket | None = None
        self._address = ""
        if socket_path:
            # "@name" is a Linux abstract-namespace socket: a leading NUL byte
            self._address = "\0" + socket_path[1:] if socket_path.startswith("@") else socket_path
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            # never block the navigation loop: a receiver that does not read (its queue holds only
            # net.unix.max_dgram_qlen = 10 datagrams) costs a counted failure, not a hang
            self._sock.setblocking(False)

    def notify(self, **fields: str | int) -> bool:
        """Send ``READY=1``-style fields (keys upper-cased); False when not sent."""
        if self._sock is None:
            return False
        msg = "\n".join(f"{k.upper()}={v}" for k, v in fields.items()).encode()
        try:
            self._sock.sendto(msg, self._address)
        except OSError:
            self.failures += 1
            return False
        return True

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
