"""The row schema (splitspec_core/model/rows.py) is the one declaration of a row's columns: the wire, the row store,
the recorder's files, the chunks and Trajectory each carry every column it declares, with its dtype and fill."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from splitspec_core.model.rows import COLUMNS, REPORTED, column, empty, present, report, run_columns, shape_of
from splitspec_core.runtime.wire import WireError, decode, encode
from splitspec_core.simulation.simulator import Trajectory
from splitspec_core.simulation.trajectory_chunks import ChunkWriter, chunk_segments, read_chunks
from splitspec_orchestrator.records.recorder import Recorder, RecordingError
from splitspec_orchestrator.records.rowstore import RowStore

os.environ.setdefault("RERUN_ANALYTICS", "0")

IDS = (1, 2, 5)
M, N, T = 3, 4, 12
RUN = "rows"


def values_of(c, rng, shape):
    """Values of column ``c``'s dtype, none of them its fill."""
    if c.dtype == "float64":
        return rng.uniform(0.5, 2.0, size=shape)
    if c.dtype == "int64":
        return rng.integers(1, 50, size=shape).astype(np.int64)
    return np.ones(shape, dtype=bool)


def test_every_column_is_declared_once_with_a_shape_a_dtype_and_a_fill():
    names = [c.name for c in COLUMNS]
    assert len(names) == len(set(names)), names
    for c in COLUMNS:
        a = empty(c, 3, M, N)
        assert a.shape == (3,) + shape_of(c, M, N) and a.dtype == np.dtype(c.dtype), c.name
        assert not present(c, a).any(), c.name  # the fill is "no value"
        assert column(c.name) is c
    assert all(c.shape == "agent" for c in REPORTED) and "g" in [c.name for c in REPORTED]
    with pytest.raises(KeyError, match="no row column"):
        column("gains")
    # a run without g (discrete time, the whole-state design) records every other reported column
    assert set(run_columns(has_g=True)) - set(run_columns(has_g=False)) == {c.name for c in REPORTED if c.only_with_g}


def test_an_xhat_carries_every_reported_column():
    rng = np.random.default_rng(1)
    given = {c.name: values_of(c, rng, ()).item() for c in REPORTED}
    msg = decode(encode("xhat", RUN, tau=3, attempt=0, agent=2, incarnation=0, x=np.arange(4.0), **report(**given),
                        rejected={}, lost=[]), RUN, "xhat")
    assert {c.name: msg[c.name] for c in REPORTED} == given  # exact: packed and unpacked, not computed
    filled = report()  # an admission report of a round's columns: their fill
    assert set(filled) == {c.name for c in REPORTED}
    assert not any(present(c, np.array([filled[c.name]], dtype=c.dtype)).any() for c in REPORTED), filled
    with pytest.raises(KeyError, match="not reported columns"):
        report(gains=1.0)
    floats = [c.name for c in REPORTED if c.dtype == "float64"]
    for name in floats:  # no NaN crosses the wire
        bad = encode("xhat", RUN, tau=3, attempt=0, agent=2, incarnation=0, x=np.arange(4.0),
                     **{**report(**given), name: float("nan")}, rejected={}, lost=[])
        with pytest.raises(WireError, match="bad_field"):
            decode(bad, RUN, "xhat")


def test_the_row_store_holds_every_column_and_takes_them_all():
    src, dst = RowStore(M, N, capacity=4), RowStore(M, N, capacity=2)
    rng = np.random.default_rng(2)
    for tau in range(6):
        k = src.append_slot(tau)
        for c in COLUMNS:
            if c.name != "tau":
                getattr(src, c.name)[k] = values_of(c, rng, shape_of(c, M, N))
    dst.take(src, 0, 6, np.zeros(0, dtype=np.int64))
    for c in COLUMNS:
        a, b = getattr(src, c.name)[:6], getattr(dst, c.name)[:6]
        assert a.dtype == np.dtype(c.dtype) and np.array_equal(a, b), c.name


def test_the_recorder_writes_every_reported_column_to_the_npz_and_the_chunks(tmp_path):
    rng = np.random.default_rng(3)
    given = {c.name: values_of(c, rng, (T, M)) for c in REPORTED}
    alive = np.ones((T, M), dtype=bool)
    alive[7:, 1] = False
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=T - 1, time_mode="discrete", dt=1.0, graph_names=("a",),
                   run_id=RUN, scenario_name="rows", flush_seconds=0, columns=run_columns(has_g=True))
    for tau in range(T):
        rec.row(tau, np.zeros(N), np.ones((M, N)), alive[tau], 0, **{k: v[tau] for k, v in given.items()})
    with pytest.raises(RecordingError, match="not a reported row column"):
        rec.row(T, np.zeros(N), np.ones((M, N)), alive[-1], 0, gains=np.ones(M))
    rec.close()
    chunks = read_chunks(tmp_path)
    with np.load(tmp_path / "trajectory.npz") as f:
        for c in REPORTED:
            want = np.where(alive, given[c.name], c.fill).astype(c.dtype)  # the fill where dead
            # exact: the values given, copied into the row store, the npz and the chunks
            assert f[c.name].dtype == np.dtype(c.dtype), c.name
            np.testing.assert_array_equal(f[c.name], want, err_msg=c.name)
            np.testing.assert_array_equal(chunks[c.name], want, err_msg=c.name)
        traj = Trajectory.load(tmp_path / "trajectory.npz")
        assert set(traj.columns) == {c.name for c in REPORTED}
        np.testing.assert_array_equal(traj.g, f["g"])


def test_chunks_written_before_a_column_existed_read_it_as_its_fill(tmp_path):
    import pyarrow as pa

    w = ChunkWriter(tmp_path, agent_ids=IDS, states=[f"x{k}" for k in range(1, N + 1)], n=N)
    cols = {c.name: empty(c, 3, M, N) for c in COLUMNS}
    cols.update(tau=np.arange(3), t=np.arange(3.0), alive=np.ones((3, M), dtype=bool), lost=[[], [], []])
    w.append(cols)
    # the same stream without the reported columns: what an older run wrote
    path = chunk_segments(tmp_path)[0][1]
    table = pa.ipc.open_stream(path.read_bytes()).read_all()  # in memory: the file is rewritten below
    old = table.drop_columns([c.name for c in REPORTED])
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_stream(sink, old.schema) as out:
        out.write_table(old)
    rows = read_chunks(tmp_path)
    assert json.loads(old.schema.metadata[b"agent_ids"]) == list(IDS)
    for c in REPORTED:
        assert rows[c.name].shape == (3, M) and not present(c, rows[c.name]).any(), c.name
    np.testing.assert_array_equal(rows["tau"], np.arange(3))
