"""Link layouts: agents as clients of the orchestrator's router (star) against peers linked to their ring neighbours.

Issue 14, item 4.  A bare zenoh-python model of the runtime's traffic on an undirected ring (every
agent hears its 2 neighbours), m agents, q exchanges, in separate OS processes on loopback (multicast
scouting off, free ports, the sessions built by the runtime's own
:func:`splitspec_core.runtime.bus.zenoh_config`: lease 10 s, keep-alive 4; publishers with congestion
control BLOCK; each message handled under one lock in the subscriber's callback thread):

* the orchestrator (a Zenoh *router*, listening) publishes ``tick(t)``, then waits for the m
  ``xhat(t)`` and ``truth(t)`` before the next tick;
* the plant (a client) answers each tick with one ``y`` (to the m agents) and one ``truth``;
* agent i, once it holds ``tick(t)``, ``y(t)`` and both neighbours' ``z(t, k - 1)`` (``z(t, 0)`` is
  their ``xhat(t - 1)``), publishes ``z(t, k)`` for k = 1..q-1 (to its 2 neighbours) and then
  ``xhat(t)`` (to the orchestrator and its 2 neighbours): 3 + mq publishes and 3m + 2 + 2mq
  deliveries per event.  Payloads 120 to 150 bytes.

Two link layouts, run interleaved (star, nbr, star, nbr...):

* ``star``: the plant and every agent are clients of the orchestrator's router (the runtime today);
* ``nbr``: the plant is a client; agent i is a *peer* listening on its own port, connected to the
  router and dialling its neighbours of higher index (one TCP link per edge of the ring, none more),
  with ``scouting/gossip/enabled: false`` (with gossip on, its default autoconnect builds the full
  mesh between the peers, and twice over).

First, the bare fan-out (``--fanout`` messages, 0 to skip): one process publishes 130-byte messages at
1 kHz (one at a time, like a z of the round, so nothing is batched) to two subscribers, through the
router (all clients) or over direct links (all peers); CPU microseconds per message of each process.

Then every round run checks (and the output reports) the links each process holds
(``session.info.routers_zid()/peers_zid()/links()``); a *direct-path probe*: the orchestrator (the
router) is frozen with SIGSTOP, every agent publishes one probe on its ``z`` key, and each agent counts
what reached it while the router was frozen and after it resumed (``nbr`` must give 2 and 2: the probes
went over the direct links; ``star`` gives 0 and 2); the liveliness tokens each process sees; and,
after the rounds, every delivery counted per message (kind, sender, t, k): a duplicate or a missing
delivery is a correctness failure, reported as an error (exit code 1).

Measured per run, after 20 warm-up rounds, over ``--steps`` rounds: ms/event (the orchestrator's wall
clock from the first tick to the last xhat), CPU (user + sys from /proc/<pid>/stat, all threads) per
event of all the processes, of the orchestrator and of the median agent, the context switches per
event, and the TCP bytes through the router's sockets per event (``ss -tin``).  The table gives the
medians over ``--repeat`` runs per layout and the medians of the ratios nbr / star of the interleaved
pairs; the 1-minute load average is printed at each run's start and end.

    .venv/bin/python benchmarks/bench_links.py [--sizes 3 32] [--q 3 6] [--steps 200] [--steps-small 1000]
        [--repeat 2] [--fanout 3000] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

from _common import loadavg

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TICK, Y, TRUTH, Z, XHAT, PROBE = range(6)
KIND = {TICK: "tick", Y: "y", TRUTH: "truth", Z: "z", XHAT: "xhat", PROBE: "probe"}
HEAD = struct.Struct("<Biii")  # kind, sender (0: orchestrator/plant, i: agent i), t, k
SIZE = {TICK: 120, Y: 150, TRUTH: 130, Z: 130, XHAT: 130, PROBE: 120}
WARM = 20
CLK = os.sysconf("SC_CLK_TCK")


def msg(kind: int, sender: int, t: int, k: int = 0) -> bytes:
    head = HEAD.pack(kind, sender, t, k)
    return head + b"\0" * (SIZE[kind] - len(head))


def ring_neighbours(i: int, m: int) -> list[int]:
    return sorted({(i - 2) % m + 1, i % m + 1})


# --------------------------------------------------------------------------- child processes

def child_session(a):
    import zenoh

    from splitspec_core.runtime.bus import zenoh_config

    if a.role == "orch":
        cfg = zenoh_config("router", listen=[a.router])
    elif a.role == "agent" and a.layout == "nbr":
        cfg = zenoh_config("peer", listen=[a.listen], connect=[a.router] + list(a.dial),
                           extra={"scouting/gossip/enabled": False})
    else:
        cfg = zenoh_config("client", connect=[a.router])
    return zenoh.open(cfg)


def fan_child(a) -> int:
    """The bare fan-out: ``--role fanpub`` publishes ``--n`` messages of 130 bytes at 1 kHz, ``fansub`` counts them."""
    import zenoh

    from splitspec_core.runtime.bus import zenoh_config

    peer = a.layout == "nbr" and a.role != "fanrouter"
    mode = "router" if a.role == "fanrouter" else "peer" if peer else "client"
    extra = {"scouting/gossip/enabled": False} if peer else None
    if mode == "router":
        cfg = zenoh_config("router", listen=[a.router])
    else:
        cfg = zenoh_config(mode, listen=[a.listen] if a.listen else None, connect=[a.router] + list(a.dial),
                           extra=extra)
    s = zenoh.open(cfg)
    n = [0]
    subs = [s.declare_subscriber("f/x", lambda _smp: n.__setitem__(0, n[0] + 1))] if a.role == "fansub" else []
    pub = s.declare_publisher("f/x", congestion_control=zenoh.CongestionControl.BLOCK) if a.role == "fanpub" else None
    print(json.dumps({"ready": a.role}), flush=True)
    sys.stdin.readline()
    if pub is not None:
        payload = b"x" * 130
        t0 = time.perf_counter()
        for k in range(a.n):
            pub.put(payload)
            while time.perf_counter() < t0 + (k + 1) * 1e-3:
                time.sleep(2e-4)
        print(json.dumps({"sent": a.n}), flush=True)
    sys.stdin.readline()
    print(json.dumps({"received": n[0]}), flush=True)
    for sub in subs:
        sub.undeclare()
    s.close()
    return 0


def child(a) -> int:
    """One process of the model: ``--role orch|plant|agent``; commands on stdin, JSON lines on stdout."""
    import zenoh

    s = child_session(a)
    block = zenoh.CongestionControl.BLOCK
    lock = threading.Lock()
    got: Counter = Counter()  # (kind, sender, t, k) -> deliveries (probes apart)
    probes: Counter = Counter()  # sender -> probe deliveries
    seen_alive: Counter = Counter()
    subs = []
    pubs = {}

    def pub(key):
        if key not in pubs:
            pubs[key] = s.declare_publisher(key, congestion_control=block)
        return pubs[key]

    def alive_cb(smp):
        with lock:
            seen_alive[(str(smp.key_expr), "delete" if smp.kind == zenoh.SampleKind.DELETE else "put")] += 1

    subs.append(s.liveliness().declare_subscriber("b/alive/**", alive_cb, history=True))
    name = "orch" if a.role == "orch" else "plant" if a.role == "plant" else f"agent{a.ident}"
    token = s.liveliness().declare_token(f"b/alive/{name}")
    out_lock = threading.Lock()

    def say(**kw):
        with out_lock:
            print(json.dumps(kw), flush=True)

    m, q = a.m, a.q
    if a.role == "orch":
        st = {"t": -1, "need": 0}
        done = threading.Event()

        def cb(smp):
            kind, sender, t, k = HEAD.unpack_from(smp.payload.to_bytes())
            with lock:
                got[(kind, sender, t, k)] += 1
                if t == st["t"] and got[(kind, sender, t, k)] == 1:
                    st["need"] -= 1
                    if st["need"] == 0:
                        done.set()

        subs.append(s.declare_subscriber("b/xhat/*", cb))
        subs.append(s.declare_subscriber("b/truth", cb))
        tick = pub("b/tick")

        def run(n: int) -> dict:
            t0 = time.perf_counter()
            for _ in range(n):
                with lock:
                    st["t"] += 1
                    t = st["t"]
                    st["need"] = m + 1
                    done.clear()
                tick.put(msg(TICK, 0, t))
                if not done.wait(30.0):
                    return {"error": f"round {t}: {st['need']} of {m + 1} messages missing after 30 s"}
            return {"wall": time.perf_counter() - t0, "rounds": n}

        def expected():
            return {(XHAT, i, t, 0) for i in range(1, m + 1) for t in range(st["t"] + 1)} | \
                   {(TRUTH, 0, t, 0) for t in range(st["t"] + 1)}
    elif a.role == "plant":
        def cb(smp):
            kind, sender, t, k = HEAD.unpack_from(smp.payload.to_bytes())
            with lock:
                got[(kind, sender, t, k)] += 1
                if got[(kind, sender, t, k)] == 1:
                    pub("b/y/all").put(msg(Y, 0, t))
                    pub("b/truth").put(msg(TRUTH, 0, t))

        subs.append(s.declare_subscriber("b/tick", cb))
        last_t = {"t": -1}

        def expected():
            return {(TICK, 0, t, 0) for t in range(last_t["t"] + 1)}
    else:
        i = a.ident
        nbrs = ring_neighbours(i, m)
        st = {"t": 0, "k": 1}  # the next message to publish: z(t, k) for k < q, xhat(t) for k = q
        have = set()  # ("tick"|"y", t) and (j, t, k): z_j(t, k); xhat_j(t) is (j, t + 1, 0)

        def advance():
            while True:
                t, k = st["t"], st["k"]
                if ("tick", t) not in have or ("y", t) not in have:
                    return
                if (t > 0 or k > 1) and any((j, t, k - 1) not in have for j in nbrs):
                    return
                if k < q:
                    pub(f"b/z/{i}").put(msg(Z, i, t, k))
                    st["k"] = k + 1
                else:
                    pub(f"b/xhat/{i}").put(msg(XHAT, i, t))
                    st["t"], st["k"] = t + 1, 1

        def cb(smp):
            kind, sender, t, k = HEAD.unpack_from(smp.payload.to_bytes())
            with lock:
                if kind == PROBE:
                    probes[sender] += 1
                    return
                got[(kind, sender, t, k)] += 1
                if got[(kind, sender, t, k)] > 1:
                    return  # a duplicate: counted, not acted upon
                if kind == TICK:
                    have.add(("tick", t))
                elif kind == Y:
                    have.add(("y", t))
                elif kind == Z:
                    have.add((sender, t, k))
                elif kind == XHAT:
                    have.add((sender, t + 1, 0))
                advance()

        for key in ["b/tick", "b/y/all"] + [f"b/z/{j}" for j in nbrs] + [f"b/xhat/{j}" for j in nbrs]:
            subs.append(s.declare_subscriber(key, cb))

        def expected():
            n = st_rounds["n"]
            e = {(TICK, 0, t, 0) for t in range(n)} | {(Y, 0, t, 0) for t in range(n)}
            for j in nbrs:
                e |= {(Z, j, t, k) for t in range(n) for k in range(1, q)} | {(XHAT, j, t, 0) for t in range(n)}
            return e
        st_rounds = {"n": 0}

    say(ready=name, zid=str(s.zid()), pid=os.getpid())
    for line in sys.stdin:
        cmd = line.split()
        if not cmd:
            continue
        if cmd[0] == "info":
            info = s.info
            say(name=name, routers=[str(z) for z in info.routers_zid()], peers=[str(z) for z in info.peers_zid()],
                links=[[str(lk.zid), lk.src, lk.dst] for lk in info.links()])
        elif cmd[0] == "run" and a.role == "orch":
            say(**run(int(cmd[1])))
        elif cmd[0] == "probe" and a.role == "agent":
            pub(f"b/z/{a.ident}").put(msg(PROBE, a.ident, -1))
            say(name=name, probed=1)
        elif cmd[0] == "probes":
            with lock:
                say(name=name, probes=dict(probes))
        elif cmd[0] == "alive":
            with lock:
                say(name=name, alive={f"{k}|{v}": c for (k, v), c in seen_alive.items()})
        elif cmd[0] == "report":  # "report <rounds run>"
            n = int(cmd[1])
            with lock:
                if a.role == "plant":
                    last_t["t"] = n - 1
                elif a.role == "agent":
                    st_rounds["n"] = n
                exp = expected()
                dup = sum(c - 1 for c in got.values() if c > 1)
                missing = len(exp - set(got))
                extra = len(set(got) - exp)
                say(name=name, deliveries=sum(got.values()), dup=dup, missing=missing, unexpected=extra)
        elif cmd[0] == "quit":
            break
    token.undeclare()
    for sub in subs:
        sub.undeclare()
    s.close()
    return 0


# --------------------------------------------------------------------------- parent

_taken: set = set()


def free_port() -> int:
    """A free port below the kernel's ephemeral range, so that no outgoing connection takes it before the child
    listens on it (with ports from the ephemeral range, one of 34 listeners of a run lost that race now and then)."""
    lo = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    rng = random.Random()
    while True:
        port = rng.randrange(max(1024, lo - 12000), lo)
        if port in _taken:
            continue
        with socket.socket() as so:
            try:
                so.bind(("127.0.0.1", port))
            except OSError:
                continue
        _taken.add(port)
        return port


def proc_cpu(pid: int) -> float:
    """User + system CPU seconds of a live process (all its threads), from /proc/<pid>/stat."""
    rest = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(rest[11]) + int(rest[12])) / CLK


def proc_switches(pid: int) -> tuple[int, int]:
    """(context switches summed over the live threads of a process, number of threads)."""
    n = threads = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            for line in (task / "status").read_text().splitlines():
                if line.startswith(("voluntary_ctxt_switches", "nonvoluntary_ctxt_switches")):
                    n += int(line.split()[1])
            threads += 1
        except OSError:
            pass
    return n, threads


def router_bytes(port: int) -> int:
    """TCP bytes sent + received so far on the router's end of every connection (``ss -tin``)."""
    r = subprocess.run(["ss", "-tinH", "state", "established", "sport", "=", f":{port}"],
                       capture_output=True, text=True)
    return sum(int(n) for n in re.findall(r"\bbytes_(?:sent|received):(\d+)", r.stdout))


class Child:
    def __init__(self, argv: list[str]):
        self.p = subprocess.Popen([sys.executable, __file__, *argv], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  text=True, bufsize=1)
        self.ready = None

    def read(self, timeout: float = 120.0) -> dict:
        box: list = []
        th = threading.Thread(target=lambda: box.append(self.p.stdout.readline()), daemon=True)
        th.start()
        th.join(timeout)
        if not box or not box[0]:
            raise RuntimeError(f"child {self.p.args[3:7]} gave no answer (exit code {self.p.poll()})")
        return json.loads(box[0])

    def ask(self, cmd: str, timeout: float = 120.0) -> dict:
        self.p.stdin.write(cmd + "\n")
        self.p.stdin.flush()
        return self.read(timeout)


def fanout(layout: str, n: int) -> dict:
    """CPU microseconds per message of each process: one publisher, two subscribers, paced at 1 kHz (no batching)."""
    router = f"tcp/127.0.0.1:{free_port()}"
    lis = [f"tcp/127.0.0.1:{free_port()}" for _ in range(2)]
    common = ["--layout", layout, "--router", router, "--n", str(n)]
    kids = {"router": Child(["--role", "fanrouter", *common])}
    kids["router"].read()
    for k in (1, 2):
        kids[f"sub{k}"] = Child(["--role", "fansub", *common, *(["--listen", lis[k - 1]] if layout == "nbr" else [])])
    kids["pub"] = Child(["--role", "fanpub", *common, *(["--dial", *lis] if layout == "nbr" else [])])
    for name in ("sub1", "sub2", "pub"):
        kids[name].read()
    time.sleep(1.5)  # the links and the subscriptions settle
    cpu0 = {name: proc_cpu(c.p.pid) for name, c in kids.items()}
    for c in kids.values():
        c.p.stdin.write("go\n")
        c.p.stdin.flush()
    kids["pub"].read(timeout=600)
    time.sleep(0.2)
    cpu1 = {name: proc_cpu(c.p.pid) for name, c in kids.items()}
    got = [kids[f"sub{k}"].ask("end")["received"] for k in (1, 2)]
    for name in ("router", "pub"):
        kids[name].ask("end")
    for c in kids.values():
        c.p.wait(timeout=20)
    us = {name: 1e6 * (cpu1[name] - cpu0[name]) / n for name in kids}
    return {**us, "total": sum(us.values()), "received": got}


def expected_links(layout: str, m: int) -> dict:
    """name -> (routers, peers) it must see."""
    agents = [f"agent{i}" for i in range(1, m + 1)]
    exp = {"plant": ({"orch"}, set())}
    if layout == "star":
        exp["orch"] = (set(), set())
        exp.update({a: ({"orch"}, set()) for a in agents})
    else:
        exp["orch"] = (set(), set(agents))
        exp.update({f"agent{i}": ({"orch"}, {f"agent{j}" for j in ring_neighbours(i, m)}) for i in range(1, m + 1)})
    return exp


def one_run(layout: str, m: int, q: int, steps: int) -> dict:
    port = free_port()
    router = f"tcp/127.0.0.1:{port}"
    aport = {i: free_port() for i in range(1, m + 1)}
    common = ["--layout", layout, "--m", str(m), "--q", str(q), "--router", router]
    load0 = loadavg(1)
    t_start = time.perf_counter()
    orch = Child(["--role", "orch", *common])
    orch.ready = orch.read()
    kids = {"orch": orch}
    kids["plant"] = Child(["--role", "plant", *common])
    for i in range(1, m + 1):
        extra = []
        if layout == "nbr":
            extra = ["--listen", f"tcp/127.0.0.1:{aport[i]}",
                     "--dial", *[f"tcp/127.0.0.1:{aport[j]}" for j in ring_neighbours(i, m) if j > i]]
        kids[f"agent{i}"] = Child(["--role", "agent", "--ident", str(i), *common, *extra])
    res: dict = {"layout": layout, "m": m, "q": q, "load": load0, "errors": []}
    try:
        for name, c in kids.items():
            if c.ready is None:
                c.ready = c.read()
        zname = {c.ready["zid"]: name for name, c in kids.items()}
        # 1. the links: wait until every process holds exactly the links of its layout
        exp = expected_links(layout, m)
        deadline = time.monotonic() + 60
        while True:
            bad, nlinks, npeer = [], 0, 0
            for name, c in kids.items():
                inf = c.ask("info")
                rs = {zname.get(z, z) for z in inf["routers"]}
                ps = {zname.get(z, z) for z in inf["peers"]}
                nlinks += len(inf["links"])
                npeer += len(ps) if name.startswith("agent") else 0
                want = exp[name]
                n_want = (m + 1) if name == "orch" else len(want[0]) + len(want[1])
                if (rs, ps) != want or len(inf["links"]) != n_want:
                    bad.append(f"{name}: routers {sorted(rs)} peers {sorted(ps)} links {len(inf['links'])}")
            if not bad or time.monotonic() > deadline:
                break
            time.sleep(0.3)
        res["links_ok"] = not bad
        res["links_total"] = nlinks  # each link counted at both of its ends
        res["direct_links"] = npeer // 2  # agent-agent links
        if bad:
            res["errors"].append("links: " + "; ".join(bad[:4]))
        res["startup_s"] = time.perf_counter() - t_start
        # 2. the liveliness tokens everybody sees
        time.sleep(0.3)
        alive = {name: c.ask("alive")["alive"] for name, c in kids.items()}
        res["orch_sees_alive"] = sum(1 for k in alive["orch"] if k.endswith("|put"))
        res["agent_sees_alive"] = statistics.median(sum(1 for k in alive[f"agent{i}"] if k.endswith("|put"))
                                                    for i in range(1, m + 1))
        # 3. the direct-path probe: freeze the router, probe every z key, count, thaw, count again
        os.kill(orch.p.pid, signal.SIGSTOP)
        try:
            for i in range(1, m + 1):
                kids[f"agent{i}"].ask("probe")
            time.sleep(0.5)
            frozen = [sum(kids[f"agent{i}"].ask("probes")["probes"].values()) for i in range(1, m + 1)]
        finally:
            os.kill(orch.p.pid, signal.SIGCONT)
        time.sleep(0.5)
        after = [sum(kids[f"agent{i}"].ask("probes")["probes"].values()) for i in range(1, m + 1)]
        res["probe_frozen"] = f"{min(frozen)}-{max(frozen)}"
        res["probe_after"] = f"{min(after)}-{max(after)}"
        if any(n != 2 for n in after):
            res["errors"].append(f"probe: deliveries per agent after the thaw {after} (2 each expected)")
        if layout == "nbr" and any(n != 2 for n in frozen):
            res["errors"].append(f"probe: deliveries per agent with the router frozen {frozen} (2 each expected: "
                                 "not over the direct links)")
        # 4. the rounds
        r = orch.ask(f"run {WARM}", timeout=300)
        if "error" in r:
            raise RuntimeError(f"warm-up: {r['error']}")
        pids = {name: c.p.pid for name, c in kids.items()}
        cpu0 = {name: proc_cpu(pid) for name, pid in pids.items()}
        sw0 = {name: proc_switches(pid) for name, pid in pids.items()}
        b0 = router_bytes(port)
        r = orch.ask(f"run {steps}", timeout=1800)
        if "error" in r:
            raise RuntimeError(f"rounds: {r['error']}")
        cpu1 = {name: proc_cpu(pid) for name, pid in pids.items()}
        sw1 = {name: proc_switches(pid) for name, pid in pids.items()}
        b1 = router_bytes(port)
        res["load_end"] = loadavg(1)
        d = {name: cpu1[name] - cpu0[name] for name in pids}
        res["ms"] = 1e3 * r["wall"] / steps
        res["cpu_ms"] = 1e3 * sum(d.values()) / steps
        res["orch_cpu_ms"] = 1e3 * d["orch"] / steps
        res["agent_cpu_ms"] = 1e3 * statistics.median(d[f"agent{i}"] for i in range(1, m + 1)) / steps
        res["router_kb"] = (b1 - b0) / 1024 / steps
        res["switches"] = sum(sw1[n][0] - sw0[n][0] for n in pids) / steps
        res["agent_threads"] = statistics.median(sw1[f"agent{i}"][1] for i in range(1, m + 1))
        res["orch_threads"] = sw1["orch"][1]
        # 5. every delivery counted once
        time.sleep(0.3)
        rounds = WARM + steps
        tot = Counter()
        for name, c in kids.items():
            rep = c.ask(f"report {rounds}")
            for key in ("deliveries", "dup", "missing", "unexpected"):
                tot[key] += rep[key]
        res.update(deliveries=tot["deliveries"], dup=tot["dup"], missing=tot["missing"], unexpected=tot["unexpected"])
        want = rounds * (3 * m + 2 + 2 * m * q)  # 3m + 2 + 2mq deliveries per event time
        if tot["dup"] or tot["missing"] or tot["unexpected"] or tot["deliveries"] != want:
            res["errors"].append(f"deliveries {tot['deliveries']} (expected {want}), duplicates {tot['dup']}, "
                                 f"missing {tot['missing']}, unexpected {tot['unexpected']}")
    finally:
        for c in kids.values():
            try:
                c.p.stdin.write("quit\n")
                c.p.stdin.flush()
            except (BrokenPipeError, OSError):
                pass
        for c in kids.values():
            try:
                c.p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                c.p.kill()
                c.p.wait()
    return res


def print_run(r: dict) -> None:
    print(f"#  m={r['m']:>2} q={r['q']} {r['layout']:>4}: {r['ms']:7.2f} ms/event, CPU {r['cpu_ms']:6.2f} ms/event "
          f"(orchestrator {r['orch_cpu_ms']:5.2f}, agent {r['agent_cpu_ms']:4.2f}), "
          f"router {r['router_kb']:5.1f} kB/event, "
          f"{r['switches']:.0f} switches/event, threads agent/orch {r['agent_threads']:g}/{r['orch_threads']}, "
          f"link ends {r['links_total']}, direct links {r['direct_links']} ({'ok' if r['links_ok'] else 'WRONG'}), "
          f"probe frozen/after {r['probe_frozen']}/{r['probe_after']}, tokens seen orch/agent "
          f"{r['orch_sees_alive']}/{r['agent_sees_alive']:g}, dup {r['dup']} missing {r['missing']}, "
          f"start {r['startup_s']:.1f} s, load {r['load']}->{r['load_end']}"
          + (f"  ERRORS: {r['errors']}" if r["errors"] else ""), flush=True)


def print_table(runs: list, sizes: list, qs: list) -> None:
    med = statistics.median
    keys = ("ms", "cpu_ms", "orch_cpu_ms", "agent_cpu_ms")
    print("\n| m | q | layout | ms/event | CPU ms/event, all | CPU ms/event, orchestrator | CPU ms/event, agent "
          "| router kB/event | links: router, direct | probe frozen/after | dup/missing | load at start, per run |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for m in sizes:
        for q in qs:
            by = {lay: [r for r in runs if (r["m"], r["q"], r["layout"]) == (m, q, lay)] for lay in ("star", "nbr")}
            if not by["star"] or not by["nbr"]:
                continue
            for lay, rs in by.items():
                print(f"| {m} | {q} | {'star (clients)' if lay == 'star' else 'neighbour peers'} | "
                      + " | ".join(f"{med(r[k] for r in rs):.2f}" for k in keys)
                      + f" | {med(r['router_kb'] for r in rs):.1f} | {m + 1}, {rs[0]['direct_links']} "
                      f"{'ok' if all(r['links_ok'] for r in rs) else 'WRONG'} "
                      f"| {rs[0]['probe_frozen']}/{rs[0]['probe_after']} "
                      f"| {sum(r['dup'] for r in rs)}/{sum(r['missing'] for r in rs)} "
                      f"| {', '.join(r['load'] for r in rs)} |")
            pairs = list(zip(by["star"], by["nbr"]))
            print(f"| {m} | {q} | nbr / star (pairs) | "
                  + " | ".join(f"{med(b[k] / a[k] for a, b in pairs):.2f}" for k in keys) + " | | | | | |", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[3, 32])
    ap.add_argument("--q", type=int, nargs="+", default=[3, 6])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--steps-small", type=int, default=1000,
                    help="rounds per run for m <= 8 (the CPU is read in 10 ms ticks)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--fanout", type=int, default=3000, help="messages of the bare fan-out measurement (0: skip it)")
    ap.add_argument("--json", type=Path, help="also write every run's figures here")
    # child processes
    ap.add_argument("--role", choices=["orch", "plant", "agent", "fanrouter", "fanpub", "fansub"])
    ap.add_argument("--layout", choices=["star", "nbr"])
    ap.add_argument("--m", type=int)
    ap.add_argument("--ident", type=int, default=0)
    ap.add_argument("--router")
    ap.add_argument("--listen")
    ap.add_argument("--dial", nargs="*", default=[])
    ap.add_argument("--n", type=int, default=0)
    a = ap.parse_args()
    if a.role in ("fanrouter", "fanpub", "fansub"):
        return fan_child(a)
    if a.role:
        a.q = a.q[0]
        return child(a)
    if min(a.sizes) < 3:
        ap.error("a ring needs m >= 3")
    print(f"# {os.cpu_count()} cpus; load average {loadavg()}; {a.steps} rounds "
          f"per run ({a.steps_small} for m <= 8) after {WARM} warm-up, {a.repeat} runs per layout, interleaved",
          flush=True)
    if a.fanout:
        fan: dict = {"star": [], "nbr": []}
        for _ in range(a.repeat):
            for layout in ("star", "nbr"):
                load = loadavg(1)
                f = fanout(layout, a.fanout)
                fan[layout].append(f)
                print(f"# fan-out {layout:>4}: CPU us/message router {f['router']:.0f}, publisher {f['pub']:.0f}, "
                      f"subscribers {f['sub1']:.0f} + {f['sub2']:.0f}, total {f['total']:.0f}; received "
                      f"{f['received']}; load {load}", flush=True)
        for layout, what in (("star", "client -> router -> 2 clients"), ("nbr", "peer -> 2 peers, direct links")):
            print(f"# fan-out median, {what}: "
                  + ", ".join(f"{k} {statistics.median(f[k] for f in fan[layout]):.0f}"
                              for k in ("router", "pub", "sub1", "sub2", "total"))
                  + " us CPU per message", flush=True)
    print("# every run (load: 1-min load average at its start and end)", flush=True)
    runs: list = []
    failed: list = []
    for m in a.sizes:
        for q in a.q:
            for _ in range(a.repeat):
                for layout in ("star", "nbr"):
                    try:
                        r = one_run(layout, m, q, a.steps_small if m <= 8 else a.steps)
                    except RuntimeError as exc:  # a round that never completed: a lost message or a dead process
                        failed.append((m, q, layout, [str(exc)]))
                        print(f"#  m={m:>2} q={q} {layout:>4}: FAILED: {exc}", flush=True)
                        continue
                    runs.append(r)
                    print_run(r)
    if a.json:
        a.json.write_text(json.dumps(runs, indent=1))
    print_table(runs, a.sizes, a.q)
    errors = failed + [(r["m"], r["q"], r["layout"], r["errors"]) for r in runs if r["errors"]]
    for e in errors:
        print("# ERROR", e)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
