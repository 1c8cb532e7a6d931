"""The two NatNet channels on UDP: commands to the server, data by multicast or unicast."""

from __future__ import annotations

import ipaddress
import select
import socket

COMMAND, DATA = "command", "data"


class UdpTransport:
    """The NatNet channels on UDP, bound to one local address (never the wildcard).

    Unicast: one socket sends to the server's command port and receives both the command
    replies (source port = command port) and the frames (source port = data port), as
    NatNet 4 clients do. Multicast: frames arrive on a second socket bound to
    (group, data port), joined on the local address. `recv` tells the channel a datagram
    came in on; datagrams from anywhere else are counted in `foreign` and dropped.
    """

    def __init__(self, server: str = "127.0.0.1", command_port: int = 1510, data_port: int = 1511,
                 multicast: str = "", local: str | None = None):
        self.server = socket.gethostbyname(server)
        self.command_port = int(command_port)
        self.data_port = int(data_port)
        self.multicast = multicast
        self.local = local or _local_address_towards(self.server)
        self.foreign = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind((self.local, 0))
        self.mcast = None
        if multicast:
            m = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            m.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            m.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            try:
                m.bind((multicast, self.data_port))
                m.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                             socket.inet_aton(multicast) + socket.inet_aton(self.local))
            except OSError:
                m.close()
                self.sock.close()
                raise
            self.mcast = m
        self._socks = [self.sock] + ([self.mcast] if self.mcast else [])

    @property
    def address(self) -> str:
        return f"{self.server}:{self.command_port}"

    def send(self, datagram: bytes) -> None:
        self.sock.sendto(datagram, (self.server, self.command_port))

    def recv(self, timeout: float) -> tuple[bytes, str] | None:
        ready, _, _ = select.select(self._socks, [], [], timeout)
        for s in ready:
            data, (host, port) = s.recvfrom(1 << 16)
            if s is self.mcast:
                return data, DATA
            if host == self.server and port == self.command_port:
                return data, COMMAND
            if host == self.server and port == self.data_port:
                return data, DATA
            self.foreign += 1
        return None

    def close(self) -> None:
        for s in self._socks:
            s.close()


def _local_address_towards(server: str) -> str:
    """The local address the kernel routes to `server` from (a UDP connect sends nothing)."""
    if ipaddress.ip_address(server).is_loopback:
        return "127.0.0.1"
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.connect((server, 9))
        return probe.getsockname()[0]
    finally:
        probe.close()
