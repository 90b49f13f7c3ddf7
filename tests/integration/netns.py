"""Several "hosts" on one machine with Linux network namespaces (needs root and iproute2).

:class:`NetnsLab` builds, for a list of host names:

* a hub namespace holding a bridge (``br0``);
* one namespace per host with ``lo`` up and ``eth0``, one end of a veth pair
  whose other end is a port of the bridge, addressed ``10.<a>.<b>.<k>/24``
  (a private subnet that exists only inside the namespaces: nothing is added
  to the machine's own network namespace);
* ``exec(host, argv)``: the command line that runs ``argv`` on that host;
* ``impair(host, delay=, jitter=, loss=)``: a misbehaving link between that host and the bridge (the
  hosts named in ``NetnsLab(..., impairable=...)``), in both directions, as Linux ``tc netem`` makes
  one: every frame is lost with probability ``loss``, else held ``delay +- jitter`` seconds (uniform;
  frames are reordered by the jitter).  Where the kernel has netem (``CONFIG_NET_SCH_NETEM``) that is
  ``tc qdisc replace dev eth0 root netem delay D J loss P`` on the host's end and the same on the
  bridge's end of its veth; where it has not (a kernel built without it, as on this project's
  machines), the host's veth ends in the hub instead of on the bridge, and a user-space emulator
  (:mod:`tests.integration.linkem`, packet sockets) carries every frame between it and a second veth
  on the bridge, dropping and holding frames the same way.  Either way the impairment is real: the
  processes' TCP stacks see frames lost, late and reordered, and retransmit; ``impair_backend`` says
  which one the lab uses, ``link_stats()`` how many frames each link carried and dropped.

Everything is removed on exit (processes in the namespaces are killed, the emulator
among them, then the namespaces, which takes their links, qdiscs and the bridge with them), also after
a failure; namespaces left by a lab whose process died are removed by the
next lab.
"""

from __future__ import annotations

import json
import os
import random
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

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


LINKEM = Path(__file__).with_name("linkem.py")
#: seconds the lab waits for the link emulator to start or to answer a command
LINKEM_TIMEOUT = 30.0


def _tc(*args, check=True) -> subprocess.CompletedProcess:
    r = subprocess.run(["tc", *args], capture_output=True, text=True)
    if check and r.returncode != 0:
        raise RuntimeError(f"tc {' '.join(args)}: {r.stderr.strip()}")
    return r


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.3f}ms"


class NetnsLab:
    """Hosts in network namespaces on one bridge; ``impairable`` hosts' links can be made to misbehave."""

    def __init__(self, hosts, *, impairable=()):
        self.hosts = list(hosts)
        self.impairable = [h for h in self.hosts if h in set(impairable)]
        if len(self.impairable) != len(set(impairable)):
            raise ValueError(f"impairable hosts {sorted(set(impairable) - set(self.hosts))} are not hosts of the lab")
        self.tag = f"{random.randrange(16 ** 4):04x}"
        self.base = f"{PREFIX}{os.getpid()}-{self.tag}"
        a, b = 10, random.randrange(100, 250)
        self.addr = {h: f"{a}.{b}.{random.randrange(1, 250)}.{k + 2}" for k, h in enumerate(self.hosts)}
        net = next(iter(self.addr.values())).rsplit(".", 1)[0]
        self.addr = {h: f"{net}.{k + 2}" for k, h in enumerate(self.hosts)}
        self.created: list = []
        #: "netem" (the kernel's qdisc) or "linkem" (the user-space emulator); None without impairable hosts
        self.impair_backend: str | None = None
        self._linkem: subprocess.Popen | None = None

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
            if self.impairable:
                self.impair_backend = "netem" if _has_netem(hub) else "linkem"
            for k, h in enumerate(self.hosts):
                ns = self.ns(h)
                _ip("netns", "add", ns)
                self.created.append(ns)
                _ip("-n", ns, "link", "set", "lo", "up")
                _ip("link", "add", "name", "eth0", "netns", ns, "type", "veth", "peer", "name", f"p{k}", "netns", hub)
                if h in self.impairable and self.impair_backend == "linkem":
                    # eth0 <-> p<k> ... emulator ... e<k> <-> b<k> (a port of the bridge)
                    _ip("-n", hub, "link", "add", f"e{k}", "type", "veth", "peer", "name", f"b{k}")
                    _ip("-n", hub, "link", "set", f"b{k}", "master", "br0")
                    for dev in (f"p{k}", f"e{k}", f"b{k}"):
                        _ip("-n", hub, "link", "set", dev, "up")
                    for dev in (f"p{k}", f"e{k}"):  # frames for the other hosts' addresses reach the emulator
                        _ip("-n", hub, "link", "set", dev, "promisc", "on")
                else:
                    _ip("-n", hub, "link", "set", f"p{k}", "master", "br0")
                    _ip("-n", hub, "link", "set", f"p{k}", "up")
                _ip("-n", ns, "addr", "add", f"{self.addr[h]}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "eth0", "up")
            if self.impair_backend == "linkem":
                self._start_linkem()
        except BaseException:
            self.close()
            raise
        return self

    # ------------------------------------------------------------------ impaired links

    def _start_linkem(self) -> None:
        import sys

        pairs = [f"{h}=p{self.hosts.index(h)}:e{self.hosts.index(h)}" for h in self.impairable]
        self._linkem = subprocess.Popen(self.exec("hub", [sys.executable, LINKEM, *pairs]), stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        if not self._linkem_reply().get("ready"):
            raise RuntimeError("the link emulator did not start")

    def _linkem_reply(self) -> dict:
        import select

        p = self._linkem
        ready, _, _ = select.select([p.stdout], [], [], LINKEM_TIMEOUT)
        line = p.stdout.readline() if ready else b""
        if not line:
            p.kill()
            raise RuntimeError(f"the link emulator gave no answer within {LINKEM_TIMEOUT:g} s (exit status "
                               f"{p.wait()}): {p.stderr.read().decode(errors='replace').strip()[-2000:]}")
        return json.loads(line)

    def _linkem_call(self, cmd: dict) -> dict:
        self._linkem.stdin.write(json.dumps(cmd).encode() + b"\n")
        self._linkem.stdin.flush()
        return self._linkem_reply()

    def impair(self, host: str, *, delay: float = 0.0, jitter: float = 0.0, loss: float = 0.0) -> None:
        """Make ``host``'s link misbehave in both directions from now on: each frame lost with probability
        ``loss``, else held ``delay`` seconds +- ``jitter`` (uniform, at least 0); all zero: a perfect link again."""
        if host not in self.impairable:
            raise ValueError(f"host {host!r} was not built impairable (NetnsLab(..., impairable=[...]))")
        if not (0.0 <= loss < 1.0 and delay >= 0.0 and jitter >= 0.0):
            raise ValueError(f"impair({host!r}): need 0 <= loss < 1, delay >= 0, jitter >= 0")
        if self.impair_backend == "linkem":
            self._linkem_call({"set": host, "delay": delay, "jitter": jitter, "loss": loss})
            return
        # tc netem on both ends of the host's veth: eth0 (host -> bridge) and p<k> (bridge -> host)
        spec = ["netem", "delay", _ms(delay), _ms(jitter), "loss", f"{loss * 100:.6f}%"]
        for ns, dev in ((self.ns(host), "eth0"), (self.ns("hub"), f"p{self.hosts.index(host)}")):
            _tc("-n", ns, "qdisc", "replace", "dev", dev, "root", *spec)

    def cut(self, host: str, off: bool = True) -> None:
        """Cut ``host`` off the network (its ``eth0`` down: no frame in or out, no FIN either), or (``off=False``)
        bring it back."""
        _ip("-n", self.ns(host), "link", "set", "eth0", "down" if off else "up")

    def link_stats(self) -> dict:
        """``{host: {"up": {"frames", "dropped"}, "down": {...}}}`` of every impairable host's link so far."""
        if self.impair_backend == "linkem":
            return self._linkem_call({"stats": True})
        out = {}
        for host in self.impairable:
            out[host] = {}
            for way, ns, dev in (("up", self.ns(host), "eth0"), ("down", self.ns("hub"), f"p{self.hosts.index(host)}")):
                text = _tc("-s", "-n", ns, "qdisc", "show", "dev", dev).stdout
                m = re.search(r"Sent \d+ bytes (\d+) pkt \(dropped (\d+)", text)
                sent, dropped = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
                out[host][way] = {"frames": sent + dropped, "dropped": dropped}
        return out

    def close(self) -> None:
        if self._linkem is not None:
            for f in (self._linkem.stdin, self._linkem.stdout, self._linkem.stderr):
                f.close()
            self._linkem.kill()  # ip netns exec execs the emulator: this is its pid
            self._linkem.wait()
            self._linkem = None
        for ns in reversed(self.created):
            _kill_and_delete(ns)
        self.created.clear()

    def __exit__(self, *exc) -> None:
        self.close()


def _has_netem(ns: str) -> bool:
    """The kernel has the netem qdisc (tried on the bridge of ``ns``, then removed); False without ``tc``."""
    if shutil.which("tc") is None:
        return False
    r = _tc("-n", ns, "qdisc", "add", "dev", "br0", "root", "netem", "delay", "0ms", check=False)
    if r.returncode != 0:
        return False
    _tc("-n", ns, "qdisc", "del", "dev", "br0", "root", check=False)
    return True
