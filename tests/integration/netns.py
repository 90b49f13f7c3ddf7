"""Several "hosts" on one machine with Linux network namespaces (needs root and iproute2).

:class:`NetnsLab` builds, for a list of host names:

* a hub namespace holding a bridge (``br0``);
* one namespace per host with ``lo`` up and ``eth0``, one end of a veth pair
  whose other end is a port of the bridge, addressed ``10.<a>.<b>.<k>/24``
  (a private subnet that exists only inside the namespaces: nothing is added
  to the machine's own network namespace);
* ``exec(host, argv)``: the command line that runs ``argv`` on that host.

Everything is removed on exit (processes in the namespaces are killed, then
the namespaces, which takes their links and the bridge with them), also after
a failure; namespaces left by a lab whose process died are removed by the
next lab.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import time

PREFIX = "sslab"  # every namespace of a lab is named sslab<pid>-<tag>-<host>


def available() -> str | None:
    """None if labs can be built here, else the reason they cannot."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is missing"
    return None


def _ip(*args, check=True) -> subprocess.CompletedProcess:
    r = subprocess.run(["ip", *args], capture_output=True, text=True)
    if check and r.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {r.stderr.strip()}")
    return r


def lab_namespaces(owner_pid: int | None = None) -> list:
    """Namespaces of labs (of one owner process, or of all)."""
    names = [line.split()[0] for line in _ip("netns", "list").stdout.splitlines() if line.strip()]
    want = f"{PREFIX}{owner_pid}-" if owner_pid is not None else PREFIX
    return [n for n in names if n.startswith(want)]


def _kill_and_delete(ns: str) -> None:
    r = _ip("netns", "pids", ns, check=False)
    for pid in r.stdout.split():
        try:
            os.kill(int(pid), signal.SIGKILL)
        except (ProcessLookupError, ValueError):
            pass
    deadline = time.monotonic() + 5
    while _ip("netns", "pids", ns, check=False).stdout.split() and time.monotonic() < deadline:
        time.sleep(0.05)
    _ip("netns", "del", ns, check=False)


def remove_stale() -> None:
    """Remove namespaces of labs whose owning process is gone."""
    for ns in lab_namespaces():
        pid = ns[len(PREFIX):].split("-", 1)[0]
        if pid.isdigit() and not os.path.exists(f"/proc/{pid}"):
            _kill_and_delete(ns)


class NetnsLab:
    def __init__(self, hosts):
        self.hosts = list(hosts)
        self.tag = f"{random.randrange(16 ** 4):04x}"
        self.base = f"{PREFIX}{os.getpid()}-{self.tag}"
        a, b = 10, random.randrange(100, 250)
        self.addr = {h: f"{a}.{b}.{random.randrange(1, 250)}.{k + 2}" for k, h in enumerate(self.hosts)}
        net = next(iter(self.addr.values())).rsplit(".", 1)[0]
        self.addr = {h: f"{net}.{k + 2}" for k, h in enumerate(self.hosts)}
        self.created: list = []

    def ns(self, host: str) -> str:
        return f"{self.base}-{host}"

    def exec(self, host: str, argv) -> list:
        return ["ip", "netns", "exec", self.ns(host), *map(str, argv)]

    def __enter__(self) -> "NetnsLab":
        remove_stale()
        try:
            hub = self.ns("hub")
            _ip("netns", "add", hub)
            self.created.append(hub)
            _ip("-n", hub, "link", "add", "br0", "type", "bridge")
            _ip("-n", hub, "link", "set", "br0", "up")
            for k, h in enumerate(self.hosts):
                ns = self.ns(h)
                _ip("netns", "add", ns)
                self.created.append(ns)
                _ip("-n", ns, "link", "set", "lo", "up")
                _ip("link", "add", "name", "eth0", "netns", ns, "type", "veth", "peer", "name", f"p{k}", "netns", hub)
                _ip("-n", hub, "link", "set", f"p{k}", "master", "br0")
                _ip("-n", hub, "link", "set", f"p{k}", "up")
                _ip("-n", ns, "addr", "add", f"{self.addr[h]}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "eth0", "up")
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        for ns in reversed(self.created):
            _kill_and_delete(ns)
        self.created.clear()

    def __exit__(self, *exc) -> None:
        self.close()
