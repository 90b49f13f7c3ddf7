"""A run's rows on disk as append-only chunks: ``chunks/rows-<tau>.arrows`` (Arrow IPC streams), written and read.

``splitspec run`` appends the rows of every flush of its recorder to the current segment file as one Arrow
record batch and never rewrites a byte: a flush costs what it adds, whatever the run's length, and a run
killed at any moment keeps every batch it finished (the reader stops at a torn last batch).  A segment is
an Arrow IPC *stream* (the schema message, then one record batch per flush; no end-of-stream marker until
the recorder closes it), so any Arrow reader opens it (``pyarrow.ipc.open_stream``, ``polars.read_ipc_stream``).
A new segment starts when the current one holds ``segment_bytes`` (64 MiB by default); its name is the
event time of its first row (``rows-000000012345.arrows``), so a time window reads only the segments it
overlaps.

Columns, one row per event time: the row schema's (:data:`splitspec_core.model.rows.COLUMNS`, in its order:
``tau`` int64, ``t`` float64, ``x`` (n), ``xhat`` (m * n, agent-major: ``xhat[i * n + k]``), ``alive`` (m) bool,
``graph`` int64, the agents' reported columns (m) such as ``g``, ``wall`` int64 (``time.time_ns()`` of the row's
arrival), ``round`` (5): the round's wall ms, attempts, messages rejected, consensus messages lost, and its
lateness against ``run.pace`` in ms (NaN unpaced)); then ``lost``: the consensus messages of this event time that
did not count, flattened ``(k, j, i, cause)`` quadruples; on measurements or live sensors ``y`` (sum s_i) and
``y_missing`` (m); and with known inputs (``system.B``) ``u`` (p), the inputs the estimators used (NaN: none).
A column the schema gained after a chunk was written reads back as its fill.  The schema's metadata holds
``agent_ids``, ``states`` (JSON) and ``dt``.  A row written again (an agent declared lost after its row was
flushed) is appended again, to the segment being written: the last batch that holds an event time wins, and a
time window reads the first segment past its end as well.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from ..model.rows import COLUMNS, ROUND_FIELDS, column, empty, shape_of

__all__ = ["CHUNKS_DIR", "ROUND_FIELDS", "ChunkWriter", "chunk_segments", "read_chunks", "has_chunks",
           "segment_last_tau"]

CHUNKS_DIR = "chunks"
_SEGMENT_BYTES = 64 << 20
_PREFIX, _SUFFIX = "rows-", ".arrows"
_FORMAT = b"splitspec-rows/1"
_EOS_LEN = 8  # the end-of-stream marker of an Arrow IPC stream (0xFFFFFFFF, then a zero length)


def _arrow_type(dtype: str):
    import pyarrow as pa

    return {"float64": pa.float64(), "int64": pa.int64(), "bool": pa.bool_()}[dtype]


def _schema(m: int, n: int, p: int, agent_ids, states, dt: float, inputs: int = 0):
    import pyarrow as pa

    fields = []
    for c in COLUMNS:  # a scalar per row, else a fixed-size list of the row's values (flattened)
        width = int(np.prod(shape_of(c, m, n), dtype=np.int64))
        typ = _arrow_type(c.dtype)
        fields.append((c.name, typ if c.shape == "row" else pa.list_(typ, width)))
    fields.append(("lost", pa.list_(pa.int64())))
    if p:
        fields += [("y", pa.list_(pa.float64(), p)), ("y_missing", pa.list_(pa.bool_(), m))]
    if inputs:
        fields.append(("u", pa.list_(pa.float64(), inputs)))
    meta = {b"format": _FORMAT, b"agent_ids": json.dumps([int(a) for a in agent_ids]).encode(),
            b"states": json.dumps([str(s) for s in states]).encode(), b"dt": repr(float(dt)).encode()}
    return pa.schema(fields, metadata=meta)


def _fixed(values: np.ndarray, width: int, typ):
    import pyarrow as pa

    flat = pa.array(np.ascontiguousarray(values).reshape(-1), type=typ)
    return pa.FixedSizeListArray.from_arrays(flat, width)


class ChunkWriter:
    """Appends rows to ``out_dir/chunks/`` (see the module docstring); the directory is made at the first append.

    Parameters
    ----------
    out_dir : str or Path
        The run's directory.
    agent_ids : sequence of int
        The agents' ids (the schema's metadata; ``m`` is their number).
    states : sequence of str
        The states' names (the schema's metadata).
    n : int
        The state dimension.
    dt : float, optional
        The sampling step (default 1: discrete time): ``t = tau * dt``, in the metadata (time windows).
    p : int, optional
        The width of ``y`` (default 0: no ``y`` / ``y_missing`` columns).
    inputs : int, optional
        The width of ``u``, the known inputs (default 0: no ``u`` column).
    segment_bytes : int, optional
        A new segment starts when the current one holds this many bytes (default 64 MiB).
    """

    def __init__(self, out_dir: str | Path, *, agent_ids, states, n: int, dt: float = 1.0, p: int = 0,
                 segment_bytes: int = _SEGMENT_BYTES, inputs: int = 0):
        self.dir = Path(out_dir) / CHUNKS_DIR
        self.m, self.n, self.p = len(agent_ids), int(n), int(p)
        self.inputs = int(inputs)
        self.schema = _schema(self.m, self.n, self.p, agent_ids, states, dt, self.inputs)
        self.segment_bytes = int(segment_bytes)
        self.path: Path | None = None  # the current segment
        self.size = 0  # its bytes on disk
        self.bytes_written = 0  # all segments' bytes written by this writer
        self.segments: list[tuple[Path, int]] = []  # (path, last tau) of the segments this writer finished
        self._name = -1  # the current segment's name (an event time)
        # zstd-compressed record batches (Arrow IPC's own buffer compression, which every Arrow reader undoes):
        # 9 % smaller on the IEEE 14-bus rows (2840 against 3111 bytes a row, 50-row batches) at no measurable cost
        import pyarrow as pa

        self._options = pa.ipc.IpcWriteOptions(compression="zstd")
        self._schema_len = len(self.schema.serialize())
        self._last_tau = -1

    def batch(self, cols: dict):
        """The record batch of ``cols``: every column of the row schema (:data:`~splitspec_core.model.rows.COLUMNS`:
        ``tau`` (L,), ``t``, ``x`` (L, n), ``xhat`` (L, m, n), ``alive`` (L, m), ``graph``, the reported columns
        (L, m) such as ``g`` (one not given: its fill), ``wall``, ``round`` (L, 5)), ``lost`` (a list of L int
        arrays of 4 k values), and
        ``y`` (L, p) / ``y_missing`` (L, m) when ``p``, ``u`` (L, inputs) when ``inputs``.

        Parameters
        ----------
        cols : dict
            Column name -> the L rows' values (shapes above).

        Returns
        -------
        pyarrow.RecordBatch
            The rows, in the writer's schema.
        """
        import pyarrow as pa

        L = len(cols["tau"])
        lost = [np.asarray(r, dtype=np.int64).reshape(-1) for r in cols["lost"]]
        arrays = []
        for c in COLUMNS:  # a reported column not given: its fill
            values = np.asarray(cols[c.name], dtype=c.dtype) if c.name in cols or not c.reported else \
                empty(c, L, self.m, self.n)
            typ = _arrow_type(c.dtype)
            arrays.append(pa.array(values) if c.shape == "row" else
                          _fixed(values, int(np.prod(shape_of(c, self.m, self.n), dtype=np.int64)), typ))
        arrays.append(pa.array(lost, type=pa.list_(pa.int64())))
        if self.p:
            arrays += [_fixed(np.asarray(cols["y"], float), self.p, pa.float64()),
                       _fixed(np.asarray(cols["y_missing"], bool), self.m, pa.bool_())]
        if self.inputs:
            arrays.append(_fixed(np.asarray(cols["u"], float), self.inputs, pa.float64()))
        assert all(len(a) == L for a in arrays)
        return pa.record_batch(arrays, schema=self.schema)

    def _encode(self, batch) -> bytes:
        """One record batch's message, zstd-compressed (``RecordBatch.serialize`` takes no options): a stream of
        it written whole, less the schema before it and the end-of-stream marker after it."""
        import pyarrow as pa

        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, self.schema, options=self._options) as w:
            w.write_batch(batch)
        data = sink.getvalue().to_pybytes()
        return data[self._schema_len:-_EOS_LEN]

    def append(self, cols: dict) -> int:
        """Append the rows ``cols`` (:meth:`batch`) as one record batch, fsynced; a new segment first when the
        current one is full.  Returns the bytes written.

        Raises
        ------
        OSError
            If the segment cannot be written; it is cut back to its last whole batch (removed if new).

        Parameters
        ----------
        cols : dict
            Column name -> the rows' values (:meth:`batch`); no row: nothing is written.

        Returns
        -------
        int
            The bytes written (the schema's too when a segment starts).
        """
        if len(cols["tau"]) == 0:
            return 0
        body = self._encode(self.batch(cols))
        new = self.path is None or self.size + len(body) > self.segment_bytes
        if new:
            self.dir.mkdir(exist_ok=True)
            if self.path is not None:
                self.segments.append((self.path, self._last_tau))
            # named by its first event time; strictly after the previous segment's name (a batch of rows
            # written again may start before it)
            self._name = max(int(np.min(cols["tau"])), self._name + 1)
            path = self.dir / f"{_PREFIX}{self._name:012d}{_SUFFIX}"
            data, mode = self.schema.serialize().to_pybytes() + body, "wb"
        else:
            path, data, mode = self.path, body, "ab"
        try:
            with open(path, mode) as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        except OSError:
            try:
                if new:
                    path.unlink(missing_ok=True)
                else:
                    os.truncate(path, self.size)
            except OSError:
                pass
            raise
        if new:
            self.path, self.size = path, 0
        self.size += len(data)
        self.bytes_written += len(data)
        self._last_tau = int(np.max(cols["tau"]))
        return len(data)

    def forget_before(self, tau: int) -> list[Path]:
        """Remove the finished segments whose rows all precede event time ``tau`` (``run.keep``); their paths.

        Parameters
        ----------
        tau : int
            The first event time kept.

        Returns
        -------
        list of Path
            The segments removed (the current segment never is).
        """
        gone = [p for p, last in self.segments if last < tau]
        for p in gone:
            p.unlink(missing_ok=True)
        self.segments = [(p, last) for p, last in self.segments if last >= tau]
        return gone


def chunk_segments(out: str | Path) -> list[tuple[int, Path]]:
    """``(first event time, path)`` of the run's segments, in order (empty when it has none).

    Parameters
    ----------
    out : str or Path
        The run's directory.

    Returns
    -------
    list of (int, Path)
        The segments sorted by their first event time (files of other names are ignored).
    """
    d = Path(out) / CHUNKS_DIR
    if not d.is_dir():
        return []
    segs = []
    for p in d.iterdir():
        if p.name.startswith(_PREFIX) and p.name.endswith(_SUFFIX):
            try:
                segs.append((int(p.name[len(_PREFIX):-len(_SUFFIX)]), p))
            except ValueError:
                continue
    return sorted(segs)


def has_chunks(out: str | Path) -> bool:
    """Whether the run's directory holds row segments (:func:`chunk_segments`).

    Parameters
    ----------
    out : str or Path
        The run's directory.

    Returns
    -------
    bool
        True when it has at least one segment.
    """
    return bool(chunk_segments(out))


def segment_last_tau(path: str | Path) -> int | None:
    """The last event time of a segment's whole record batches (a torn last batch left out), None when it holds
    none: with :func:`chunk_segments`, where a run's rows end without reading them all.

    Parameters
    ----------
    path : str or Path
        A segment file.

    Returns
    -------
    int or None
        The ``tau`` of its last whole row.
    """
    last = None
    for batch in _batches(Path(path)):
        if batch.num_rows:
            last = int(batch.column("tau")[batch.num_rows - 1].as_py())
    return last


def _batches(path: Path) -> Iterator:
    """The whole record batches of a segment (a torn last batch, from a kill mid-write, is left out)."""
    import pyarrow as pa

    try:
        reader = pa.ipc.open_stream(pa.memory_map(str(path)))
    except (OSError, pa.ArrowInvalid):
        return  # not even a whole schema: a segment created as the run was killed
    while True:
        try:
            yield reader.read_next_batch()
        except StopIteration:
            return
        except (OSError, pa.ArrowInvalid):
            return


def whole_length(path: str | Path) -> int:
    """Bytes of a segment's whole messages (what ``splitspec recover`` cuts a torn segment back to).

    Parameters
    ----------
    path : str or Path
        A segment file.

    Returns
    -------
    int
        The bytes of its schema and whole record batches (0 when not even the schema is whole).
    """
    import pyarrow as pa

    size = os.path.getsize(path)
    good = 0
    with pa.memory_map(str(path)) as stream:  # not read into memory: a segment is up to 64 MiB
        try:
            reader = pa.ipc.open_stream(stream)
            good = stream.tell()
            while True:
                reader.read_next_batch()
                good = stream.tell()
        except StopIteration:
            pass
        except (OSError, pa.ArrowInvalid):
            pass
    return min(good, size)


def read_chunks(out: str | Path, *, start: float | None = None, end: float | None = None) -> dict | None:
    """The rows of a run's chunks with ``start <= t <= end`` (None: no bound), as arrays; None if it has none.

    Returns every column of the row schema (:data:`splitspec_core.model.rows.COLUMNS`: ``tau``, ``t``, ``x``,
    ``xhat`` (T, m, n), ``alive``, ``graph``, the reported columns such as ``g`` (T, m), ``wall``, ``round``
    (T, 5, :data:`ROUND_FIELDS`)), ``agent_ids``, ``lost`` (N, 4), ``lost_cause``, ``states``, and
    ``y``/``y_missing`` and ``u`` (T, p) when recorded: one row per event time, in order, the last one written
    where an event time was written twice.

    Parameters
    ----------
    out : str or Path
        The run's directory.
    start : float or None, optional
        The first time kept (inclusive); None (default): from the beginning.
    end : float or None, optional
        The last time kept (inclusive); None (default): to the end.

    Returns
    -------
    dict or None
        Array name -> array, as above (:meth:`~splitspec_core.simulation.simulator.Trajectory.from_arrays`
        reads it); None when the run has no segment or no readable schema.

    Examples
    --------
    >>> import tempfile
    >>> import numpy as np
    >>> with tempfile.TemporaryDirectory() as out:
    ...     w = ChunkWriter(out, agent_ids=[1, 2], states=("a", "b"), n=2)
    ...     _ = w.append(dict(tau=np.arange(3), t=np.arange(3.0), x=np.zeros((3, 2)), xhat=np.ones((3, 2, 2)),
    ...                       alive=np.ones((3, 2), dtype=bool), graph=np.zeros(3, dtype=int),
    ...                       wall=np.zeros(3, dtype=int), round=np.zeros((3, 5)), lost=[[], [1, 2, 1, 0], []]))
    ...     rows = read_chunks(out, start=1.0)
    >>> rows["tau"], rows["xhat"].shape, rows["lost"], rows["lost_cause"]
    (array([1, 2]), (2, 2, 2), array([[1, 1, 2, 1]]), array([0], dtype=int8))
    """
    import pyarrow as pa

    segs = chunk_segments(out)
    if not segs:
        return None
    dt = _dt_of(segs[0][1])
    firsts = [f for f, _ in segs]
    chosen = []
    for k, (first, path) in enumerate(segs):
        # segment k holds the rows from its first event time up to the next one's first, and rows written
        # again a little later: it may hold event times up to the first of segment k + 2
        if end is not None and k > 0 and firsts[k - 1] * dt > end:
            break  # (the first segment past the window is read: it may hold rows of the window written again)
        if start is not None and k + 2 < len(firsts) and firsts[k + 2] * dt < start:
            continue
        chosen.append(path)
    batches, schema = [], None
    for path in chosen:
        for b in _batches(path):
            schema = b.schema
            batches.append(b)
    if schema is None:
        schema = _schema_of(segs[0][1])
        if schema is None:
            return None
    meta = schema.metadata or {}
    agent_ids = np.array(json.loads(meta[b"agent_ids"]), dtype=np.int64)
    states = tuple(json.loads(meta[b"states"]))
    m, n = len(agent_ids), len(states)
    table = pa.Table.from_batches(batches, schema=schema)

    def col(name, width=None, dtype=float):
        c = table.column(name).combine_chunks() if table.num_rows else None
        if c is None:
            return np.zeros((0,) if width is None else (0, width), dtype=dtype)
        if width is None:
            return c.to_numpy(zero_copy_only=False).astype(dtype)
        return c.flatten().to_numpy(zero_copy_only=False).astype(dtype).reshape(-1, width)

    def schema_col(c):
        """Column ``c`` of the row schema, one row per row of the table; its fill where the chunks lack it."""
        shape = shape_of(c, m, n)
        if c.name not in table.column_names:
            return empty(c, table.num_rows, m, n)
        flat = col(c.name, None if not shape else int(np.prod(shape, dtype=np.int64)), c.dtype)
        return flat.reshape((-1,) + shape)

    tau = schema_col(column("tau"))
    # the last row written of each event time, in event-time order
    rev = tau[::-1]
    _, first_rev = np.unique(rev, return_index=True)
    keep = (len(tau) - 1 - first_rev)  # sorted by tau (np.unique sorts)
    t = schema_col(column("t"))[keep]
    if start is not None or end is not None:
        sel = np.ones(len(keep), dtype=bool)
        if start is not None:
            sel &= t >= start
        if end is not None:
            sel &= t <= end
        keep, t = keep[sel], t[sel]
    out_arrays = {c.name: schema_col(c)[keep] for c in COLUMNS if c.name not in ("tau", "t")}
    out_arrays.update(tau=tau[keep], t=t, agent_ids=agent_ids, states=states)
    lost_col = table.column("lost").to_pylist() if table.num_rows else []
    quads = [np.asarray(lost_col[int(k)], dtype=np.int64).reshape(-1, 4) for k in keep]
    rows = [np.column_stack([np.full(len(qd), tv, dtype=np.int64), qd]) for tv, qd in zip(out_arrays["tau"], quads)
            if len(qd)]
    lost5 = np.concatenate(rows) if rows else np.zeros((0, 5), dtype=np.int64)
    order = np.lexsort(tuple(lost5[:, c] for c in (3, 2, 1, 0))) if len(lost5) else np.zeros(0, dtype=np.int64)
    lost5 = lost5[order]
    out_arrays["lost"], out_arrays["lost_cause"] = lost5[:, :4].copy(), lost5[:, 4].astype(np.int8)
    if "y" in table.column_names:
        p = table.schema.field("y").type.list_size
        out_arrays["y"] = col("y", p)[keep]
        out_arrays["y_missing"] = col("y_missing", m, bool)[keep]
    if "u" in table.column_names:
        out_arrays["u"] = col("u", table.schema.field("u").type.list_size)[keep]
    return out_arrays


def _dt_of(path: Path) -> float:
    schema = _schema_of(path)
    try:
        return float((schema.metadata or {})[b"dt"])
    except (AttributeError, KeyError, ValueError):
        return 1.0


def _schema_of(path: Path):
    import pyarrow as pa

    try:
        return pa.ipc.open_stream(pa.memory_map(str(path))).schema
    except (OSError, pa.ArrowInvalid):
        return None
