"""A user-space link emulator: what ``tc qdisc ... netem delay D J loss P`` does, for kernels built without netem.

Run inside a namespace as ``python linkem.py NAME=A:B ...``: for every pair of interfaces ``A`` and ``B``
it forwards each Ethernet frame that arrives on one to the other (an Ethernet cable with a box in the
middle), after dropping it with probability ``loss`` or holding it ``delay + jitter (2u - 1)`` seconds
(``u`` uniform in ``[0, 1)``, at least 0), as netem does with its default uniform jitter: frames are
released in the order of their release times, so jitter reorders them, as netem's does.  ``A -> B`` is
the pair's ``up`` direction, ``B -> A`` its ``down`` direction.  The frames are real: the TCP stacks on
either side see them lost, late or out of order, and retransmit.

Frames are read and written with packet sockets and their ``virtio_net_hdr`` (``PACKET_VNET_HDR``), so
checksum offload and segmentation offload pass through untouched (a veth leaves TCP checksums to the
receiver, and hands large TCP segments over whole).

Protocol on stdin/stdout, one JSON object a line: it prints ``{"ready": true}`` once every socket is
bound; then answers each command line with one line:

* ``{"set": NAME, "delay": s, "jitter": s, "loss": p}``: impair both directions of pair ``NAME``
  (from the next frame on) -> ``{"ok": true}``;
* ``{"stats": true}`` -> ``{"NAME": {"up": {"frames": .., "dropped": ..}, "down": {...}}, ...}``.

It ends when stdin closes, or when it is killed.  Standard library only.
"""

from __future__ import annotations

import heapq
import json
import os
import random
import select
import socket
import sys
import time

SOL_PACKET = 263
PACKET_VNET_HDR = 15
ETH_P_ALL = 0x0003
FRAME_MAX = 1 << 18  # a whole GSO super-frame (up to 64 KB) and its header


def open_port(ifname: str) -> socket.socket:
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.setsockopt(SOL_PACKET, PACKET_VNET_HDR, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
    s.bind((ifname, ETH_P_ALL))
    s.setblocking(False)
    return s


class Direction:
    def __init__(self, out: socket.socket):
        self.out = out
        self.delay = self.jitter = self.loss = 0.0
        self.frames = self.dropped = 0


def main(argv: list) -> int:
    rng = random.Random(int.from_bytes(os.urandom(8), "little"))
    pairs, goes = {}, {}  # goes: socket -> the direction its frames take
    for spec in argv:
        name, _, ends = spec.partition("=")
        a, _, b = ends.partition(":")
        sa, sb = open_port(a), open_port(b)
        up, down = Direction(sb), Direction(sa)
        pairs[name] = (up, down)
        goes[sa], goes[sb] = up, down
    held: list = []  # (release time, sequence number, direction, frame)
    seq = 0
    stdin = sys.stdin.fileno()
    print(json.dumps({"ready": True}), flush=True)
    pending = b""
    while True:
        timeout = None if not held else max(0.0, held[0][0] - time.monotonic())
        ready, _, _ = select.select([stdin, *goes], [], [], timeout)
        now = time.monotonic()
        for sock in ready:
            if sock == stdin:
                continue
            d = goes[sock]
            while True:
                try:
                    frame, addr = sock.recvfrom(FRAME_MAX)
                except BlockingIOError:
                    break
                if addr[2] == socket.PACKET_OUTGOING:  # our own transmission on this port
                    continue
                d.frames += 1
                if d.loss > 0 and rng.random() < d.loss:
                    d.dropped += 1
                    continue
                hold = max(0.0, d.delay + d.jitter * (2.0 * rng.random() - 1.0)) if d.delay or d.jitter else 0.0
                if hold == 0.0 and not held:
                    send(d, frame)
                else:
                    heapq.heappush(held, (now + hold, seq, d, frame))
                    seq += 1
        if stdin in ready:  # after the frames that arrived with it: stats count them
            chunk = os.read(stdin, 65536)
            if not chunk:
                return 0
            pending += chunk
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                if line.strip():
                    print(json.dumps(command(json.loads(line), pairs)), flush=True)
        now = time.monotonic()
        while held and held[0][0] <= now:
            _, _, d, frame = heapq.heappop(held)
            send(d, frame)


def send(d: Direction, frame: bytes) -> None:
    try:
        d.out.send(frame)
    except OSError:  # the link is going away (the lab is being removed), or the frame is refused: lost
        d.dropped += 1


def command(cmd: dict, pairs: dict) -> dict:
    if "set" in cmd:
        for d in pairs[cmd["set"]]:
            d.delay, d.jitter, d.loss = float(cmd["delay"]), float(cmd["jitter"]), float(cmd["loss"])
        return {"ok": True}
    if "stats" in cmd:
        return {name: {"up": {"frames": up.frames, "dropped": up.dropped},
                       "down": {"frames": down.frames, "dropped": down.dropped}}
                for name, (up, down) in pairs.items()}
    return {"error": f"unknown command {cmd!r}"}


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
