"""ROS domains and local ports for tests, claimed across processes.

Two pytest-xdist workers, two pytest runs on one machine, a bench started by hand: each
test that starts ROS 2 nodes needs a ROS_DOMAIN_ID nobody else is on, and each fake
server (NatNet) a port nobody else listens on. A pid-derived number does not give that
(two workers' pids meet modulo any range). A claim here does:

- a domain is claimed by an exclusive, non-blocking ``flock`` on
  ``<tmp>/dvrk-rig-test-locks/domain-<n>.lock``, held until the claim is released (or the
  process dies: the kernel drops the lock with the file descriptor, so a crashed run
  leaves nothing to clean up). Locks are advisory: everyone running these tests takes
  them, so concurrent runs never share a domain.
- a domain with a DDS participant already on it (somebody's experiment started by hand,
  which takes no lock) is skipped too: Fast DDS binds the unicast metatraffic port
  7400 + 250 d + 10 + 2 p of participant p on domain d, so a port that cannot be bound
  means the domain is in use.
- tests draw from 1-149 (never 0, every ROS user's default): the lab runs experiments and
  benches by hand on 150-169 and 200-232. ``RIG_TEST_DOMAINS=first-last`` changes it.
- ports are claimed the same way (``port-<n>.lock``), ``count`` consecutive ones, each
  checked free by binding it (TCP and UDP) on 127.0.0.1; drawn from 6100-7399, below
  every DDS domain's ports (7400 + 250 d ...) and the kernel's ephemeral range.

Use them as context managers (``with claim_domain() as d:``) or through the fixtures in
tests/conftest.py (``ros_domain``, ``ros_env``, ``free_port``).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import random
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

#: the domains the lab's engineers use by hand (experiments, benches): never drawn
HAND_DOMAINS = frozenset(range(150, 170)) | frozenset(range(200, 233))
DEFAULT_DOMAINS = range(1, 150)
PORTS = range(6100, 7400)


def lock_folder() -> Path:
    """The folder every test run on this machine shares (mode 1777, as /tmp)."""
    folder = Path(os.environ.get("RIG_TEST_LOCKS") or Path(tempfile.gettempdir()) / "dvrk-rig-test-locks")
    try:
        folder.mkdir(mode=0o1777, parents=True, exist_ok=True)
        os.chmod(folder, 0o1777)
    except PermissionError:  # made by another user: it is already shared
        pass
    return folder


def domain_range() -> list[int]:
    """The domains tests draw from: $RIG_TEST_DOMAINS (``first-last``) or 1-149."""
    spec = os.environ.get("RIG_TEST_DOMAINS", "").strip()
    if not spec:
        return [d for d in DEFAULT_DOMAINS if d not in HAND_DOMAINS]
    first, _, last = spec.partition("-")
    domains = [d for d in range(int(first), int(last or first) + 1) if 1 <= d <= 232]
    if not domains:
        raise ValueError(f"RIG_TEST_DOMAINS={spec!r} names no domain in 1-232")
    return domains


class Claim:
    """Held locks on one or more numbers (a domain, or consecutive ports); ``value`` is the first."""

    def __init__(self, kind: str, values: list[int], fds: list[int]):
        self.kind, self.values, self._fds = kind, values, fds

    @property
    def value(self) -> int:
        return self.values[0]

    def release(self) -> None:
        for fd in self._fds:
            with contextlib.suppress(OSError):
                os.close(fd)  # closing the descriptor drops its flock
        self._fds = []

    def __enter__(self) -> int:
        return self.value

    def __exit__(self, *exc) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"Claim({self.kind} {self.values}{'' if self._fds else ', released'})"


def _lock(kind: str, n: int) -> int | None:
    """An fd holding the exclusive lock on `kind`-`n`, or None if someone holds it."""
    path = lock_folder() / f"{kind}-{n}.lock"
    fd = os.open(path, os.O_RDONLY | os.O_CREAT | os.O_CLOEXEC, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        os.close(fd)
        if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise
    return fd


def _bindable(port: int, kinds=(socket.SOCK_STREAM, socket.SOCK_DGRAM)) -> bool:
    """Can `port` be bound on 127.0.0.1 (for every socket kind in `kinds`) right now?"""
    for kind in kinds:
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def dds_in_use(domain: int, participants: int = 4) -> bool:
    """Does a DDS participant (Fast DDS's default ports) sit on `domain` already?"""
    base = 7400 + 250 * domain + 10
    return not all(_bindable(base + 2 * p, (socket.SOCK_DGRAM,)) for p in range(participants))


def _order(candidates: list[int]) -> list[int]:
    """The candidates from a random start, round: concurrent claimers rarely try the same first."""
    start = random.SystemRandom().randrange(len(candidates))
    return candidates[start:] + candidates[:start]


def claim_domain(domains: list[int] | None = None) -> Claim:
    """A ROS domain nobody else is on, held until ``release()`` (or the process ends)."""
    candidates = list(domains or domain_range())
    for d in _order(candidates):
        fd = _lock("domain", d)
        if fd is None:
            continue
        if dds_in_use(d):  # somebody's nodes, started without a lock
            os.close(fd)
            continue
        return Claim("domain", [d], [fd])
    raise RuntimeError(f"no free ROS domain among {candidates[0]}-{candidates[-1]}: every one is locked by a "
                       f"test run or has DDS participants on it (locks in {lock_folder()})")


def claim_ports(count: int = 1, ports: range = PORTS) -> Claim:
    """`count` consecutive free local ports (TCP and UDP on 127.0.0.1), held until released."""
    firsts = list(range(ports.start, ports.stop - count + 1, count))
    for first in _order(firsts):
        fds: list[int] = []
        for p in range(first, first + count):
            fd = _lock("port", p)
            if fd is None or not _bindable(p):
                if fd is not None:
                    os.close(fd)
                break
            fds.append(fd)
        if len(fds) == count:
            return Claim("port", list(range(first, first + count)), fds)
        for fd in fds:
            os.close(fd)
    raise RuntimeError(f"no {count} consecutive free ports in {ports.start}-{ports.stop - 1}")


@contextlib.contextmanager
def ros_environment(domain: int) -> Iterator[int]:
    """os.environ on `domain` with localhost-only discovery for the block (restored after)."""
    keys = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")
    saved = {k: os.environ.get(k) for k in keys}
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    try:
        yield domain
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
