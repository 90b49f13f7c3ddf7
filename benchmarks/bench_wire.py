"""The codec's cost per round message: today's binary layout and keyed-BLAKE2b trailer against the schema-2 form.

Schema 2 (before issue 14's codec) sent every message as a msgpack map (version, run id, type, fields; the vector
as ``{"shape", "data"}``) with an HMAC-SHA256 trailer; it is rebuilt here only as the reference. For each round
message at n = 6: bytes on the wire (signed), and microseconds to encode and to decode (verify + validate), the
median of ``--repeat`` interleaved timings of ``--number`` calls each.

    .venv/bin/python benchmarks/bench_wire.py [--n 6] [--number 20000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import hashlib
import hmac
import statistics
import timeit

import msgpack
import numpy as np

from splitspec_core.runtime.wire import decode, encode, new_run_key

from _common import loadavg

RUN = "default"


def schema2_encode(msg_type, key, **fields):
    body = {"v": 2, "run": RUN, "type": msg_type}
    for k, v in fields.items():
        body[k] = {"shape": list(v.shape), "data": np.ascontiguousarray(v, "<f8").tobytes()} \
            if isinstance(v, np.ndarray) else v
    raw = msgpack.packb(body, use_bin_type=True)
    return raw + hmac.digest(key, raw, hashlib.sha256)[:16]


def schema2_decode(payload, key, msg_type, names):
    body, tag = payload[:-16], payload[-16:]
    if not hmac.compare_digest(hmac.digest(key, body, hashlib.sha256)[:16], tag):
        raise ValueError("bad_mac")
    m = msgpack.unpackb(body, raw=False, strict_map_key=True)
    if m.get("v") != 2 or m.get("run") != RUN or m.get("type") != msg_type:
        raise ValueError("header")
    out = {}
    for k in names:
        v = m[k]
        if isinstance(v, dict) and set(v) == {"shape", "data"}:
            a = np.frombuffer(v["data"], dtype="<f8").reshape(v["shape"]).astype(float)
            if not np.all(np.isfinite(a)):
                raise ValueError("non_finite")
            v = a
        out[k] = v
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--number", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args(argv)
    key, v = new_run_key(), np.linspace(-1, 1, a.n)
    msgs = {
        "y": dict(tau=7, attempt=0, y=v),
        "truth": dict(tau=7, attempt=0, x=v, rejected={}),
        "z": dict(tau=7, attempt=0, k=1, agent=3, z=v),
        "xhat": dict(tau=7, attempt=0, agent=3, incarnation=0, x=v, g=1.0, rejected={}),
    }
    load = loadavg()
    print(f"codec per message, n = {a.n}, median of {a.repeat} x {a.number} calls (load {load})")
    print(f"{'message':8} {'bytes v2':>9} {'bytes now':>9} {'enc v2 us':>10} {'enc now':>8} {'dec v2 us':>10} "
          f"{'dec now':>8} {'enc+dec ratio':>14}")
    for t, f in msgs.items():
        p_new, p_old = encode(t, RUN, mac_key=key, **f), schema2_encode(t, key, **f)
        assert set(decode(p_new, RUN, t, mac_key=key)) == set(schema2_decode(p_old, key, t, f)) == set(f)
        cases = {
            "enc2": lambda: schema2_encode(t, key, **f), "enc": lambda: encode(t, RUN, mac_key=key, **f),
            "dec2": lambda: schema2_decode(p_old, key, t, f), "dec": lambda: decode(p_new, RUN, t, mac_key=key),
        }
        us = {k: [] for k in cases}
        for _ in range(a.repeat):  # interleaved
            for k, fn in cases.items():
                us[k].append(timeit.timeit(fn, number=a.number) / a.number * 1e6)
        med = {k: statistics.median(x) for k, x in us.items()}
        ratio = (med["enc"] + med["dec"]) / (med["enc2"] + med["dec2"])
        print(f"{t:8} {len(p_old):9d} {len(p_new):9d} {med['enc2']:10.2f} {med['enc']:8.2f} {med['dec2']:10.2f} "
              f"{med['dec']:8.2f} {ratio:13.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
