"""Wire format and key space of the runtime (pure: no sockets).

Two encodings, one API (:func:`encode`, :func:`decode`):

* the messages of every round (``y``, ``truth``, ``z`` (``r`` for the relay kind), ``xhat``: all but a
  handful per event time) are compact binary: a fixed little-endian header
  (magic ``0xB5``, schema version, type code, the row schema's tag (:data:`ROW_TAG`: a process
  built with other reported row columns is ``bad_version``), CRC-32 of the run id, the
  message's integer and float fields), one float64 vector (its length, then
  the data) and, for ``truth``/``xhat``, the rejection counters as a msgpack
  map (and for ``xhat`` the consensus messages not counted, a msgpack list); a signed ``z`` of n = 6 is 96 bytes (129 as the schema-2 msgpack map),
  encoded and decoded, MAC included, in less than half the time
  (``benchmarks/bench_wire.py``);
* the rest (``tick``, ``control``, ``config``, ``hello``, ``refused``) are
  msgpack maps with the schema version ``v``, the run id ``run``, the
  message ``type`` and its fields (no arrays).

:func:`decode` validates everything (version, type, run id, fields and their
ranges, lengths to the byte, shapes, finiteness) and raises
:class:`WireError` with a short reason, which the receiving process counts
and logs; nothing that fails validation is used.

Authentication: every message after the configuration (tick, y, truth, z,
xhat, control) carries a 16-byte trailer, keyed BLAKE2b-128 of the body
under the run's key (:func:`new_run_key`).  The orchestrator hands the key
only to the processes it admits (in the ``config`` reply to an accepted
``hello``), so a Zenoh client that was never admitted cannot forge a tick,
a measurement or a stop, even without ``--secure``'s access control.  What
this does not stop (an admitted process forging another's messages, a
passive listener) is what ``--secure``'s per-process credentials and the
router's access-control policy are for.

Identity: each plant or agent process draws a random ``nonce`` at start and
sends it in its ``hello``; its liveliness token and status queryable carry
it (``alive/<role>/<id>/<nonce>``), so two processes claiming the same id
are two different tokens, and the orchestrator knows which one it admitted.

Keys live under ``splitspec/<run_id>/`` (:class:`Keys` builds all of them):

==========================  ======================  ==========================================
key                         from -> to              payload
==========================  ======================  ==========================================
``config``                  queryable (orchestr.)   scenario + centralised design (g or q)
``tick``                    orchestrator -> all     tau, attempt, graph, final, fresh, prev_attempt, topology;
                                                    if it changed: rows, alive, incarnation, partition
``y/all``                   plant -> agents         tau, attempt, (y_1(tau), ..., y_m(tau)) stacked,
                                                    the agents without a measurement (missing)
``truth``                   plant -> orchestrator   tau, attempt, x(tau)
``z/<i>``                   agent i -> neighbours   tau, attempt, k, z_i(k) (k = 0 only in fresh or re-run
                                                    rounds); the relay kind's ``r``: tau, attempt, k, the
                                                    samples it has not sent (values; sensor and t of each)
``xhat/<i>``                agent i -> orchestrator tau, attempt, x_i(tau) (+ its reported row columns, g_i
                            and neighbours          ..., rejected counts, the consensus messages it did not count, the y_i it
                                                    used: None without one, [] if not recorded);
                                                    also the next round's z_i(0)
``sensors/<key>``            sensor -> agent i       y_i as JSON ``{"y": [...], "t": ...}`` or raw float64 (scenario
                                                    ``sources:``; unsigned, see :mod:`splitspec_agents.sensor`)
``control``                 orchestrator -> all     ``stop``; ``kill agent/<i>``, ``freeze agent/<i>`` (faults)
``state``                   orchestrator -> standby its epoch, the process table (pid, host, nonce), the pace's
                                                    origin (wall clock), tau, the rows on disk: what a takeover needs
``status/<role>/<id>/<n>``  queryable (every proc.) a ``hello``: the process answers (not frozen)
``alive/<role>/<id>/<n>``   liveliness token        presence; DELETE is a death (n: the process's nonce)
==========================  ======================  ==========================================

Why one module: the encoder and the decoder read the same tables (the fields and their kinds, the binary layout,
the schema version, the MAC); split, every change of the format would touch two files that must agree byte for
byte, and the key space above is the other half of the same contract.
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import math
import secrets
import struct
import zlib
from dataclasses import dataclass

import msgpack
import numpy as np

from ..errors import SplitspecError
from ..model.rows import REPORTED

__all__ = ["SCHEMA_VERSION", "DEFAULT_RUN_ID", "Keys", "WireError", "encode", "decode",
           "MESSAGE_FIELDS", "MAC_BYTES", "new_run_key", "new_nonce", "mac", "verify",
           "BINARY_LAYOUT", "ROW_TAG", "run_tag", "KEY_ROOT", "ORCHESTRATORS"]

# 2: one y message for every agent; x_i(tau + 1) doubles as the next z_i(0); 3: binary round messages;
# 4: xhat reports the consensus messages that did not count, tick names the partition in force; 5: y names the
# agents without a measurement (missing), xhat carries the measurement the agent used (y); 6: a tick carries the
# network (rows, alive, incarnation, partition: O(m) to decode in every agent) only when it changed (topology); 7: a
# config carries W, the directions no agent sees (unobserved: the estimator's P_i projects on V_i minus W); 8: xhat
# carries the reported row columns of splitspec_core.model.rows, the binary header's fourth byte tags them (ROW_TAG);
# 9: xhat carries the live known inputs the agent used (u)
SCHEMA_VERSION = 9
DEFAULT_RUN_ID = "default"
KEY_ROOT = "splitspec"  #: every run's keys live under ``splitspec/<run_id>/``
#: every run's orchestrator token (``splitspec/<run_id>/alive/orchestrator/0``): which runs a router hosts
ORCHESTRATORS = f"{KEY_ROOT}/*/alive/orchestrator/*"


class WireError(SplitspecError, ValueError):
    """A message failed validation; ``reason`` is a short tag for counting."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


@dataclass(frozen=True)
class Keys:
    """The key expressions of one run."""

    run_id: str = DEFAULT_RUN_ID

    def __post_init__(self):
        bad = set("/*$?#") & set(self.run_id)
        if not self.run_id or bad:
            raise SplitspecError(f"--run-id must be non-empty without / * $ ? #, got {self.run_id!r}")

    @property
    def prefix(self) -> str:
        """The run's key prefix ``splitspec/<run_id>`` (str)."""
        return f"{KEY_ROOT}/{self.run_id}"

    @property
    def config(self) -> str:
        """The key of the configuration queryable, ``<prefix>/config`` (str)."""
        return f"{self.prefix}/config"

    @property
    def tick(self) -> str:
        """The key of the orchestrator's ticks, ``<prefix>/tick`` (str)."""
        return f"{self.prefix}/tick"

    @property
    def truth(self) -> str:
        """The key of the plant's true states, ``<prefix>/truth`` (str)."""
        return f"{self.prefix}/truth"

    @property
    def control(self) -> str:
        """The key of the orchestrator's commands (stop, kill, freeze), ``<prefix>/control`` (str)."""
        return f"{self.prefix}/control"

    @property
    def state(self) -> str:
        """The key of the active orchestrator's state for a standby, ``<prefix>/state`` (str)."""
        return f"{self.prefix}/state"

    @property
    def orchestrators(self) -> str:
        """Every orchestrator token of this run, ``<prefix>/alive/orchestrator/*`` (the id is its epoch)."""
        return f"{self.prefix}/alive/orchestrator/*"

    @property
    def standbys(self) -> str:
        """Every standby orchestrator token of this run, ``<prefix>/alive/standby/**``."""
        return f"{self.prefix}/alive/standby/**"

    @property
    def y(self) -> str:
        """Every agent's measurement, stacked in agent order (one message per event time)."""
        return f"{self.prefix}/y/all"

    def z(self, i: int | str) -> str:
        """The key of agent ``i``'s consensus messages.

        Parameters
        ----------
        i : int or str
            The agent's id.

        Returns
        -------
        str
            ``<prefix>/z/<i>``.

        Examples
        --------
        >>> Keys("demo").z(3)
        'splitspec/demo/z/3'
        """
        return f"{self.prefix}/z/{i}"

    def sensor(self, key: str) -> str:
        """A live sensor's key (scenario ``sources:``, relative to ``sensors/``): the user's process publishes there.

        Parameters
        ----------
        key : str
            The sensor's key relative to ``sensors/``, as the scenario's ``sources:`` gives it.

        Returns
        -------
        str
            ``<prefix>/sensors/<key>``.
        """
        return f"{self.prefix}/sensors/{key}"

    def xhat(self, i: int | str) -> str:
        """The key of agent ``i``'s estimates (read by the orchestrator and its neighbours).

        Parameters
        ----------
        i : int or str
            The agent's id.

        Returns
        -------
        str
            ``<prefix>/xhat/<i>``.
        """
        return f"{self.prefix}/xhat/{i}"

    def status(self, role: str, ident: int | str = 0, nonce: str | None = None) -> str:
        """The key of a process's status queryable.

        Parameters
        ----------
        role : str
            The process's role (``plant``, ``agent``, ``orchestrator``, ...).
        ident : int or str, optional
            The process's id (default 0; an agent's id).
        nonce : str or None, optional
            The process's nonce (:func:`new_nonce`); None (default): the key without it.

        Returns
        -------
        str
            ``<prefix>/status/<role>/<ident>[/<nonce>]``.
        """
        base = f"{self.prefix}/status/{role}/{ident}"
        return base if nonce is None else f"{base}/{nonce}"

    @property
    def status_all(self) -> str:
        """Every process's status queryable, ``<prefix>/status/**`` (str)."""
        return f"{self.prefix}/status/**"

    def alive(self, role: str, ident: int | str = 0, nonce: str | None = None) -> str:
        """The key of a process's liveliness token.

        Parameters
        ----------
        role : str
            The process's role (``plant``, ``agent``, ``orchestrator``, ...).
        ident : int or str, optional
            The process's id (default 0; an agent's id).
        nonce : str or None, optional
            The process's nonce (:func:`new_nonce`); None (default): the key without it.

        Returns
        -------
        str
            ``<prefix>/alive/<role>/<ident>[/<nonce>]``.

        Examples
        --------
        >>> k = Keys("demo")
        >>> k.alive("agent", 2, "00ff")
        'splitspec/demo/alive/agent/2/00ff'
        >>> k.parse_member(k.alive("agent", 2, "00ff"))
        ('agent', 2, '00ff')
        """
        base = f"{self.prefix}/alive/{role}/{ident}"
        return base if nonce is None else f"{base}/{nonce}"

    def parse_member(self, key: str, kind: str = "alive") -> tuple | None:
        """``(role, id, nonce)`` of a ``<kind>/<role>/<id>[/<nonce>]`` key of this run, else None.

        Parameters
        ----------
        key : str
            A key (anything ``str()`` turns into one).
        kind : str, optional
            The member kind, ``"alive"`` (default) or ``"status"``.

        Returns
        -------
        tuple of (str, int, str or None) or None
            ``(role, id, nonce)`` (nonce None when the key has none); None when the key is not under
            ``<prefix>/<kind>/``, has not two or three chunks there, or its id is not a decimal number.
        """
        head = f"{self.prefix}/{kind}/"
        key = str(key)
        if not key.startswith(head):
            return None
        parts = key[len(head):].split("/")
        if len(parts) not in (2, 3) or not parts[1].isdigit():
            return None
        return parts[0], int(parts[1]), parts[2] if len(parts) == 3 else None

    @property
    def alive_all(self) -> str:
        """Every process's liveliness token, ``<prefix>/alive/**`` (str)."""
        return f"{self.prefix}/alive/**"

    @staticmethod
    def run_of(key: str) -> str | None:
        """The run id of a key under ``splitspec/<run_id>/`` (e.g. a reply to :data:`ORCHESTRATORS`), else None.

        Parameters
        ----------
        key : str
            A key (anything ``str()`` turns into one).

        Returns
        -------
        str or None
            The chunk after ``splitspec/``; None when the key is not under ``splitspec/`` or that chunk
            is empty.
        """
        root, sep, rest = str(key).partition("/")
        run_id = rest.partition("/")[0]
        return run_id if root == KEY_ROOT and sep and run_id else None

    @staticmethod
    def last(key: str) -> str:
        """Last chunk of a key (the agent id of ``.../z/3``).

        Parameters
        ----------
        key : str
            A key (anything ``str()`` turns into one).

        Returns
        -------
        str
            The text after the last ``/`` (the whole key when it has none).
        """
        return str(key).rsplit("/", 1)[-1]


# --------------------------------------------------------------------------
# authentication
# --------------------------------------------------------------------------

MAC_BYTES = 16


def new_run_key() -> bytes:
    """A fresh random key for one run (32 bytes).

    Returns
    -------
    bytes
        32 bytes from :mod:`secrets`.
    """
    return secrets.token_bytes(32)


def new_nonce() -> str:
    """A process's identity nonce (16 hex characters).

    Returns
    -------
    str
        16 lowercase hex characters from :mod:`secrets`.
    """
    return secrets.token_hex(8)


def mac(key: bytes, body: bytes) -> bytes:
    """The trailer: BLAKE2b in its keyed (MAC) mode, ``MAC_BYTES`` long (RFC 7693; a third of HMAC-SHA256's cost).

    Parameters
    ----------
    key : bytes
        The run's key (:func:`new_run_key`; at most 64 bytes).
    body : bytes
        The message's body.

    Returns
    -------
    bytes
        The ``MAC_BYTES``-long tag.
    """
    return hashlib.blake2b(body, key=key, digest_size=MAC_BYTES).digest()


# --------------------------------------------------------------------------
# messages
# --------------------------------------------------------------------------

#: required fields (name -> kind) of the msgpack messages; the round messages' are in :data:`BINARY_LAYOUT`
MESSAGE_FIELDS = {
    "tick": {"tau": "int", "attempt": "int", "graph": "int", "final": "bool", "fresh": "bool", "prev_attempt": "int",
             "topology": "int"},
    "control": {"cmd": "str"},
    "config": {"scenario": "str", "seed": "int", "g": "any", "q": "any", "g_mode": "any", "key": "bytes"},
    "refused": {"reason": "str", "holder_pid": "int", "holder_host": "str"},
    "hello": {"role": "str", "id": "int", "pid": "int", "host": "str", "nonce": "str"},
    "state": {"epoch": "int", "procs": "map", "t_run_wall": "any", "tau": "int", "pid": "int", "host": "str",
              "kept": "int"},
}

#: optional fields (name -> kind), returned only when present: a run on recorded measurements (their sha256, steps,
#: whether they hold the truth), whether agents report the y_i they used, the directions no agent sees (W, n rows of
#: w numbers: splitspec_core.model.detectability), the agent's gain when the design chose it centrally ({K, consensus,
#: P}: splitspec_core.synthesis.whole_state.agent_gain), the agent's bad-data test ({S_inv, threshold, suspect_after}:
#: splitspec_core.synthesis.bad_data.agent_config); a tick's network; the epoch of the orchestrator that sent a tick,
#: a control or a config (fencing: a process ignores a tick or control of an epoch below the highest it has seen)
OPTIONAL_FIELDS = {"config": {"measurements": "map", "record_y": "bool", "unobserved": "list", "gain": "map",
                              "bad_data": "map", "epoch": "int", "standby": "bool"},
                   "tick": {"alive": "list", "rows": "map", "incarnation": "map", "partition": "list", "epoch": "int"},
                   "control": {"epoch": "int"}}
#: optional fields that come all together or not at all: a tick's network is all four (runtime.ticks)
TOGETHER = {"tick": ("alive", "rows", "incarnation", "partition")}

_CHECK = {
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
    "str": lambda v: isinstance(v, str),
    "bool": lambda v: isinstance(v, bool),
    "list": lambda v: isinstance(v, list),
    "map": lambda v: isinstance(v, dict),
    "bytes": lambda v: isinstance(v, bytes),
    "any": lambda v: True,
}


# --------------------------------------------------------------------------
# binary round messages
# --------------------------------------------------------------------------

BINARY_MAGIC = 0xB5  # never the first byte of a msgpack map (0x80-0x8f, 0xde, 0xdf)
MAX_VECTOR = 1 << 20

_STRUCT_CODE = {"float64": "d", "int64": "q", "bool": "?"}
#: type -> (code, struct format of the scalar fields, their names, the vector field, the map fields); an ``xhat``
#: carries one scalar field per column the agents report (:data:`splitspec_core.model.rows.REPORTED`, in its order)
BINARY_LAYOUT = {
    "y": (1, "qi", ("tau", "attempt"), "y", ("missing",)),
    "truth": (2, "qi", ("tau", "attempt"), "x", ("rejected",)),
    "z": (3, "qiii", ("tau", "attempt", "k", "agent"), "z", ()),
    # the relay kind's exchange (synthesis/relay.py): the samples' values side by side, then which they are
    "r": (5, "qiii", ("tau", "attempt", "k", "agent"), "z", ("samples",)),
    "xhat": (4, "qiii" + "".join(_STRUCT_CODE[c.dtype] for c in REPORTED),
             ("tau", "attempt", "agent", "incarnation", *(c.name for c in REPORTED)), "x",
             ("rejected", "lost", "y", "u")),
}
_FLOAT_FIELDS = frozenset(c.name for c in REPORTED if c.dtype == "float64")  # finite: no NaN on the wire
#: the binary header's tag of the row schema's reported columns (their names and dtypes, in order)
ROW_TAG = zlib.crc32(";".join(f"{c.name}:{c.dtype}" for c in REPORTED).encode()) & 0xFF
#: fields a sender may leave out (the usual case): ``missing`` none, ``y`` / ``u`` not recorded, a reported row
#: column whose fill can cross the wire (not NaN): its fill
MAP_DEFAULTS = {"y": {"missing": []}, "xhat": {"y": [], "u": [], **{c.name: c.fill for c in REPORTED
                                                            if c.dtype != "float64" or math.isfinite(c.fill)}}}
#: the most agent ids ``missing`` lists
MAX_MISSING = 1 << 16
#: ``lost`` of an ``xhat``: flat ``[k, j, cause, k, j, cause, ...]`` (sub-round, sender, cause) of the consensus
#: messages the agent did not count in the round (:mod:`splitspec_core.model.impairment`); at most this many triples
MAX_LOST = 1 << 16
_BIN_HEAD = struct.Struct("<BBBBI")  # magic, version, type code, ROW_TAG, CRC-32 of the run id
_BIN = {t: struct.Struct("<BBBBI" + fmt + "I") for t, (_, fmt, *_rest) in BINARY_LAYOUT.items()}
_BIN_BY_CODE = {code: t for t, (code, *_rest) in BINARY_LAYOUT.items()}
_BIN_FIELDS = {t: frozenset({*names, vec, *maps}) for t, (_, _f, names, vec, maps) in BINARY_LAYOUT.items()}


@functools.lru_cache(maxsize=64)
def run_tag(run_id: str) -> int:
    """The run id as the binary header carries it (CRC-32; the MAC trailer is what authenticates).

    Parameters
    ----------
    run_id : str
        The run id.

    Returns
    -------
    int
        CRC-32 of the run id's UTF-8 bytes (an unsigned 32-bit integer).
    """
    return zlib.crc32(run_id.encode("utf-8"))


def _encode_binary(msg_type: str, run_id: str, fields: dict) -> bytes:
    code, _fmt, names, vec, maps = BINARY_LAYOUT[msg_type]
    if msg_type in MAP_DEFAULTS:
        fields = {**MAP_DEFAULTS[msg_type], **fields}
    if fields.keys() != _BIN_FIELDS[msg_type]:
        raise TypeError(f"{msg_type} takes the fields {sorted(_BIN_FIELDS[msg_type])}, got {sorted(fields)}")
    a = np.ascontiguousarray(fields[vec], dtype="<f8")
    if a.ndim != 1:
        raise ValueError(f"{msg_type}.{vec} must be a vector, got shape {a.shape}")
    try:
        body = _BIN[msg_type].pack(BINARY_MAGIC, SCHEMA_VERSION, code, ROW_TAG, run_tag(run_id),
                                   *(fields[n] for n in names), a.size) + a.tobytes()
    except struct.error as exc:  # a field of the wrong type or out of its range: the caller's bug
        raise TypeError(f"{msg_type}: {exc} ({', '.join(f'{n}={fields[n]!r}' for n in names)})") from None
    for name in maps:
        body += msgpack.packb(fields[name], use_bin_type=True)
    return body


def _decode_binary(payload: bytes, run_id: str, expected_type: str) -> dict:
    if len(payload) < _BIN_HEAD.size:
        raise WireError("garbage", "truncated header")
    _, version, code, rows, tag = _BIN_HEAD.unpack_from(payload)
    if version != SCHEMA_VERSION:
        raise WireError("bad_version", f"schema {version}")
    if rows != ROW_TAG:
        raise WireError("bad_version", f"row schema tag {rows}, expected {ROW_TAG}")
    if tag != run_tag(run_id):
        raise WireError("wrong_run", "another run's message")
    if _BIN_BY_CODE.get(code) != expected_type:
        raise WireError("wrong_type", f"type {_BIN_BY_CODE.get(code, code)!r}, expected {expected_type}")
    _, _fmt, names, vec, maps = BINARY_LAYOUT[expected_type]
    st = _BIN[expected_type]
    if len(payload) < st.size:
        raise WireError("garbage", "truncated fields")
    values = st.unpack_from(payload)[5:]
    count, end = values[-1], st.size + 8 * values[-1]
    if count > MAX_VECTOR or len(payload) < end or (not maps and len(payload) != end):
        raise WireError("bad_shape", f"{vec}: {len(payload) - st.size} bytes for {count} numbers")
    out = dict(zip(names, values))
    for name in _FLOAT_FIELDS.intersection(out):
        if not math.isfinite(out[name]):
            raise WireError("bad_field", name)
    if count <= 64:  # the usual state sizes: checked in Python, a third of numpy's per-call cost
        vals = struct.unpack_from(f"<{count}d", payload, st.size)
        if not all(map(math.isfinite, vals)):
            raise WireError("non_finite", f"{vec} has NaN or inf")
        out[vec] = np.array(vals, dtype=float)
    else:
        a = np.frombuffer(payload, dtype="<f8", count=count, offset=st.size).astype(float)
        if not np.isfinite(a).all():
            raise WireError("non_finite", f"{vec} has NaN or inf")
        out[vec] = a
    if maps:  # the rejection counters (a map str -> int), then for xhat the lost triples: to the last byte
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=len(payload))
        unpacker.feed(payload[end:])
        try:
            objs = [unpacker.unpack() for _ in maps]
        except Exception as exc:  # noqa: BLE001 - any decoder failure (or too few objects) is garbage on the wire
            raise WireError("garbage", type(exc).__name__) from None
        if unpacker.tell() != len(payload) - end:
            raise WireError("garbage", "trailing bytes")
        for name, m in zip(maps, objs):
            if name == "lost":
                ok = (isinstance(m, list) and len(m) % 3 == 0 and len(m) <= 3 * MAX_LOST
                      and all(_CHECK["int"](v) and 0 <= v < 2 ** 31 for v in m) and all(c <= 2 for c in m[2::3]))
            elif name == "samples":  # flat [sensor, t, sensor, t, ...] of an r message's values, in order
                ok = (isinstance(m, list) and len(m) % 2 == 0 and len(m) <= 2 * MAX_MISSING
                      and all(_CHECK["int"](v) and 0 <= v < 2 ** 62 for v in m))
            elif name == "missing":
                ok = isinstance(m, list) and len(m) <= MAX_MISSING and all(_CHECK["int"](v) and 0 <= v < 2 ** 31
                                                                            for v in m)
            elif name in ("y", "u"):
                ok = m is None or (isinstance(m, list) and len(m) <= MAX_VECTOR and all(map(_CHECK["float"], m)))
                if ok and m is not None:
                    m = [float(v) for v in m]
            else:
                ok = isinstance(m, dict) and all(isinstance(k, str) and _CHECK["int"](v) for k, v in m.items())
            if not ok:
                raise WireError("bad_field", name)
            out[name] = m
    return out


def encode(msg_type: str, run_id: str, *, mac_key: bytes | None = None, **fields) -> bytes:
    """Encode a message; with ``mac_key`` the MAC trailer is appended.

    Round messages (:data:`BINARY_LAYOUT`) take exactly their fields, the vector as any 1-D float
    array; the others are msgpack maps of plain values.

    Parameters
    ----------
    msg_type : str
        The message type: a key of :data:`BINARY_LAYOUT` (``y``, ``truth``, ``z``, ``xhat``) or of
        :data:`MESSAGE_FIELDS` (``tick``, ``control``, ``config``, ``refused``, ``hello``).
    run_id : str
        The run id the message belongs to.
    mac_key : bytes or None, optional
        The run's key; None (default): no MAC trailer.
    **fields
        The message's fields.  A round message takes exactly its fields (those of
        :data:`MAP_DEFAULTS` may be left out); a msgpack message is not checked here.

    Returns
    -------
    bytes
        The payload (body, then the ``MAC_BYTES`` trailer when signed).

    Raises
    ------
    TypeError
        A round message with missing or extra fields, or a field of the wrong type or range.
    ValueError
        A round message's vector that is not 1-D.

    Examples
    --------
    >>> import numpy as np
    >>> key = bytes(32)
    >>> payload = encode("z", "demo", mac_key=key, tau=4, attempt=0, k=1, agent=2, z=np.array([0.5, -1.0]))
    >>> len(payload)
    64
    >>> msg = decode(payload, "demo", "z", mac_key=key)
    >>> msg["tau"], msg["agent"], msg["z"]
    (4, 2, array([ 0.5, -1. ]))
    >>> decode(payload, "other", "z", mac_key=key)
    Traceback (most recent call last):
        ...
    splitspec_core.runtime.wire.WireError: wrong_run: another run's message
    """
    if msg_type in BINARY_LAYOUT:
        raw = _encode_binary(msg_type, run_id, fields)
        return raw if mac_key is None else raw + mac(mac_key, raw)
    raw = msgpack.packb({"v": SCHEMA_VERSION, "run": run_id, "type": msg_type, **fields}, use_bin_type=True)
    return raw if mac_key is None else raw + mac(mac_key, raw)


def verify(payload: bytes, mac_key: bytes) -> bytes:
    """The body of a signed message, or :class:`WireError` ``bad_mac`` (cheap: run it before decoding).

    Parameters
    ----------
    payload : bytes
        A signed message (body then trailer).
    mac_key : bytes
        The run's key.

    Returns
    -------
    bytes
        The body, the trailer removed.

    Raises
    ------
    WireError
        ``bad_mac``: the payload is too short, or its trailer is not the body's MAC under ``mac_key``.
    """
    if len(payload) <= MAC_BYTES:
        raise WireError("bad_mac", "too short for a signed message")
    body, tag = payload[:-MAC_BYTES], payload[-MAC_BYTES:]
    if not hmac.compare_digest(mac(mac_key, body), tag):
        raise WireError("bad_mac", "not signed with the run's key")
    return body


def decode(payload: bytes, run_id: str, expected_type: str, *, mac_key: bytes | None = None) -> dict:
    """Decode and validate one message of ``expected_type`` for ``run_id``.

    With ``mac_key`` the message must carry a valid trailer (:func:`verify`).
    A round message's vector is returned as a finite float64 1-D array; its
    length is checked by the caller, which knows it.

    Parameters
    ----------
    payload : bytes
        The message as received.
    run_id : str
        The run id the message must belong to.
    expected_type : str
        The message type expected on this key (:data:`BINARY_LAYOUT` or :data:`MESSAGE_FIELDS`).
    mac_key : bytes or None, optional
        The run's key; None (default): the payload is not signed.

    Returns
    -------
    dict
        The message's fields: every required field, the optional ones present, and for a round
        message its vector (a float64 1-D array) and map fields.

    Raises
    ------
    WireError
        ``bad_mac``, ``garbage``, ``bad_version``, ``wrong_run``, ``wrong_type``,
        ``missing_field``, ``bad_field``, ``bad_shape`` or ``non_finite``.
    """
    if mac_key is not None:
        payload = verify(payload, mac_key)
    if payload[:1] == b"\xb5":
        return _decode_binary(payload, run_id, expected_type)
    try:
        body = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # noqa: BLE001 - any decoder failure is garbage on the wire
        raise WireError("garbage", type(exc).__name__) from None
    if not isinstance(body, dict):
        raise WireError("garbage", "not a map")
    if body.get("v") != SCHEMA_VERSION:
        raise WireError("bad_version", f"schema {body.get('v')!r}")
    if expected_type in BINARY_LAYOUT:
        raise WireError("garbage", f"a {expected_type} message is binary, not a map")
    if body.get("run") != run_id:
        raise WireError("wrong_run", f"run {body.get('run')!r}")
    if body.get("type") != expected_type:
        raise WireError("wrong_type", f"type {body.get('type')!r}, expected {expected_type}")
    out = {}
    for name, kind in MESSAGE_FIELDS[expected_type].items():
        if name not in body:
            raise WireError("missing_field", name)
        v = body[name]
        if not _CHECK[kind](v):
            raise WireError("bad_field", name)
        out[name] = v
    for name, kind in OPTIONAL_FIELDS.get(expected_type, {}).items():
        if name in body:
            if not _CHECK[kind](body[name]):
                raise WireError("bad_field", name)
            out[name] = body[name]
    group = TOGETHER.get(expected_type, ())
    missing = [name for name in group if name not in out]
    if missing and len(missing) < len(group):
        raise WireError("missing_field", missing[0])
    return out
