"""A standby's takeover: the records it goes on with, the fencing on disk, and the handover to the round machine.

When the active orchestrator's token goes, the standby (:mod:`splitspec_orchestrator.standby`) becomes an
:class:`~splitspec_orchestrator.driver.Orchestrator` of the next epoch and, before its first round:

1. makes the dead one's records agree (:func:`resume_records`, as :func:`~.records.recover.recover` does but
   without reading them all: a torn chunk batch and a torn line of ``events.jsonl`` cut, the ``run.rrd`` segment
   that was being written finished by a child process beside the run, as a rolled one is), and goes on in the same folder: the
   chunks and ``events.jsonl`` appended, ``run.rrd`` in the next segment, ``trajectory.npz`` rebuilt from every
   chunk at the close;
2. holds the records (:func:`hold_records`): ``.orchestrator.json`` names the epoch that writes them; an
   orchestrator of a lower epoch that finds it (one cut off from the network, then back) stands down without
   writing anything more (the driver's ``_check_held``);
3. records the rounds the dead one committed and had not written (its follower kept them), then hands the round
   in flight, the network and the process table to :func:`~.rounds.follower.adopt`
   (:func:`take_over`); the events ``orchestrator_lost`` and ``orchestrator_takeover`` (with the stall: the time
   between the last tick of the dead one and the first of the new one) say so.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from pathlib import Path

from splitspec_core.runtime.node import settle_heap

log = logging.getLogger("splitspec.orchestrator")

__all__ = ["HOLDER_FILE", "STATE_SECONDS", "StandbyLink", "hold_records", "records_holder", "resume_records",
           "take_over", "took_over", "warm"]

HOLDER_FILE = ".orchestrator.json"  #: the epoch (and pid, host) of the orchestrator that writes a run's records
STATE_SECONDS = 1.0  #: a run with a standby: the active orchestrator publishes its state at least this often


class StandbyLink:
    """The active orchestrator's side of its standbys (``orch``: the :class:`~splitspec_orchestrator.driver.
    Orchestrator`): their hellos and tokens, and the state it publishes for them.

    A standby says hello (it gets the scenario, the key and the epoch), subscribes, then shows its token
    (``alive/standby/0/<nonce>``): the next tick carries the network for it and the state goes out at once
    (``standby_joined``); a second token (``alive/standby/1/<nonce>``) says it is ready to take over with nothing
    lost (``standby_ready``: the records on disk reach the first round it followed).
    """

    def __init__(self, orch):
        self.orch = orch
        self.hellos: dict = {}  # nonce -> (pid, host) of the standbys that said hello
        self.next_state = 0.0  # when the state is published next

    def hello(self, h: dict) -> bytes:
        """A standby's hello (decoded): the ``config`` to answer it with."""
        from splitspec_core.runtime.wire import encode

        o = self.orch
        o.standby = True
        self.hellos[h["nonce"]] = (int(h["pid"]), str(h["host"]))
        return encode("config", o.keys.run_id, scenario=o.scenario_text, seed=int(o.sc.run.seed), g=o.des.g, q=o.des.q,
                      g_mode=o.des.g_mode, key=o.key, epoch=o.epoch)

    def token(self, nonce: str | None, up: bool, ready: bool = False) -> list:
        """A standby's token (``ready``: its second) appeared or went: the actions."""
        from .rounds.actions import Event, Log

        if nonce not in self.hellos:
            return []  # not this one's standby (the token of the standby it was, before its takeover)
        pid, host = self.hellos[nonce]
        t = self.orch.machine.t()
        if ready:
            return [Event("standby_ready", t, {"pid": pid, "host": host}),
                    Log("info", f"the standby orchestrator (pid {pid} on {host}) is ready to take over")] if up else []
        if not up:
            self.hellos.pop(nonce, None)
            return [Event("standby_left", t, {"pid": pid, "host": host})]
        self.orch.ticks.resend_network()
        self.next_state = 0.0
        return [Event("standby_joined", t, {"pid": pid, "host": host}),
                Log("info", f"a standby orchestrator (pid {pid} on {host}) follows the run")]

    def publish_state(self, now: float) -> None:
        """What a standby needs to take over (:class:`~splitspec_orchestrator.rounds.follower.Follower`): the epoch,
        the process table with nonces, the pace's origin on the wall clock, the rows on disk; about once a second
        and at every change of the process table."""
        from splitspec_core.runtime.wire import encode

        o, m = self.orch, self.orch.machine
        t_run_wall = None if m.t_run is None else time.time() - (time.monotonic() - m.t_run)
        o.pub_state.put(encode("state", o.keys.run_id, mac_key=o.key, epoch=o.epoch, procs=m.identity.state(),
                               t_run_wall=t_run_wall, tau=int(m.tau), pid=os.getpid(), host=socket.gethostname(),
                               kept=int(o.rec.rows_kept)))
        self.next_state = now + STATE_SECONDS

    def held_by_another(self) -> str:
        """Whether an orchestrator of a higher epoch holds the records (this one was cut off and a standby took
        over): then this one stands down at once, writing nothing more (``orch.superseded``, the reason; else "")."""
        o = self.orch
        held = records_holder(o.out)
        if held is None or held.get("epoch", 0) <= o.epoch:
            if o.standby and o.connect and not _router_link(o):  # cut off: a standby may be taking over as this one decides
                o.superseded = (f"this orchestrator (epoch {o.epoch}) lost its link to the run's router: a standby "
                                "takes the run over; this one stands down and writes nothing more")
            return o.superseded
        o.superseded = (f"orchestrator epoch {held['epoch']} (pid {held.get('pid')} on {held.get('host')}) took this "
                        f"run over; this one (epoch {o.epoch}) stands down and writes nothing more")
        return o.superseded


def _router_link(orch) -> bool:
    """Whether ``orch``'s session still has its link to the run's router (a client's)."""
    try:
        return bool(orch.session.info.routers_zid())
    except Exception:  # noqa: BLE001 - a session closing under us has no link
        return False


def hold_records(out: Path, epoch: int) -> None:
    """Write ``out/.orchestrator.json``: this process, of orchestrator epoch ``epoch``, writes the records now.

    Parameters
    ----------
    out : Path
        The run's output folder.
    epoch : int
        The orchestrator's epoch (1, and one more at each takeover).
    """
    path = Path(out) / HOLDER_FILE
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"epoch": int(epoch), "pid": os.getpid(), "host": socket.gethostname(),
                               "wall": time.time()}), encoding="utf-8")
    os.replace(tmp, path)


def records_holder(out: Path) -> dict | None:
    """Who holds a run's records (``epoch``, ``pid``, ``host``), or None when nobody says so (or it cannot be read).

    Parameters
    ----------
    out : Path
        The run's output folder.

    Returns
    -------
    dict or None
        The content of ``.orchestrator.json``.
    """
    try:
        held = json.loads((Path(out) / HOLDER_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return held if isinstance(held, dict) and isinstance(held.get("epoch"), int) else None


def resume_records(out: Path) -> tuple:
    """Make the dead orchestrator's records agree, fast, and say where the standby goes on.

    The chunks are the authority (as for :func:`~.records.recover.recover`): a torn last batch is cut, and the rows
    on disk K are event times 0..K-1 (only the last segment is read).  A torn last line of ``events.jsonl`` is cut
    and the recorder's leftovers removed.  The ``run.rrd`` segment the dead one was writing is left for the new
    recorder to finish beside the run (``Recorder.finish_beside``: a torn message cut, ``rerun rrd optimize`` at the
    lowest priority, as a rolled segment), not before its next round.

    Parameters
    ----------
    out : Path
        The run's output folder (the dead orchestrator's).

    Returns
    -------
    tuple of (int, int, Path or None)
        K (the standby records from event time K on), the ``run.rrd`` segment the standby writes (the one after
        the last that exists) and the dead one's segment to finish (None: none is without its footer).
    """
    from splitspec_core.simulation.trajectory_chunks import chunk_segments, segment_last_tau, whole_length

    from .records.outdir import RESERVE_FILE
    from .viewer.rrd_file import has_footer, rrd_index, rrd_segments
    from .viewer.sink import RRD_FILE

    out = Path(out)
    rows = 0
    for _, path in reversed(chunk_segments(out)):  # the last segment was being written: it may be torn or empty
        whole = whole_length(path)
        if whole == 0:
            path.unlink()
            continue
        if whole < path.stat().st_size:
            os.truncate(path, whole)
        last = segment_last_tau(path)
        if last is not None:
            rows = last + 1
            break
    _cut_torn_line(out / "events.jsonl")
    for leftover in [out / RESERVE_FILE, *out.glob(".trajectory.*.npz.tmp"), *out.glob(".run.*.rrd.tmp")]:
        leftover.unlink(missing_ok=True)
    segments = rrd_segments(out / RRD_FILE)
    torn = segments[-1] if segments and not has_footer(segments[-1]) else None
    last = max((rrd_index(p) for p in segments), default=-1)
    return rows, last + 1, torn


def finish_left_segments(out: Path, args: dict | None) -> None:
    """At the end of a run that was taken over: every ``run.rrd`` segment still without its footer is finished and
    waited for, so that the run's records are complete when it exits.  Such a segment is a dead orchestrator's last
    rolled one, whose finishing child (its own session: the kill does not stop it) may still be at work, or not yet
    started on it: :func:`~.viewer.rrd_file.finish_in_child` takes the segment's lock, waits for that child, and
    then finds the footer and leaves the file alone.

    Parameters
    ----------
    out : Path
        The run's output folder.
    args : dict or None
        The layout's arguments (:meth:`~.records.recorder.Recorder.layout_args`); None: the run has no Rerun
        recording.
    """
    from .viewer.rrd_file import finish_in_child, has_footer, rrd_index, rrd_segments, wait_finished
    from .viewer.sink import RRD_FILE

    if args is None:
        return
    wait_finished([finish_in_child(p, args, has_layout=rrd_index(p) == 0)
                   for p in rrd_segments(Path(out) / RRD_FILE) if not has_footer(p)])


def _cut_torn_line(events: Path) -> None:
    """Cut a last line of ``events.jsonl`` that the kill left without its newline."""
    try:
        data = events.read_bytes()
    except OSError:
        return
    if data and not data.endswith(b"\n"):
        os.truncate(events, data.rfind(b"\n") + 1)


def warm() -> None:
    """Import what a takeover needs (the recorder and Rerun, the chunks' reader): 0.8 s of imports a standby pays
    while it follows, not while the rounds stall."""
    import pyarrow.ipc  # noqa: F401
    import rerun  # noqa: F401
    import rerun.blueprint  # noqa: F401

    from splitspec_core.simulation import trajectory_chunks  # noqa: F401
    from splitspec_core.simulation.simulator import Trajectory  # noqa: F401

    from .records import recorder  # noqa: F401
    from .registry import RunRegistry  # noqa: F401
    from .rounds import follower  # noqa: F401
    from .viewer import rrd_file  # noqa: F401


def take_over(orch, now: float) -> None:
    """Hand the followed run to ``orch``'s round machine (see the module docstring, step 3).

    Parameters
    ----------
    orch : splitspec_orchestrator.driver.Orchestrator
        The standby turned active: ``orch.takeover`` holds its follower and what it knew at the loss.
    now : float
        The monotonic time.
    """
    from .rounds.follower import adopt

    view, info = orch.takeover
    m = orch.machine
    orch.tally.event_times = orch.first_row  # the rows its predecessors recorded count in the run's totals
    t = m.t(view.round.tau)
    orch.rec.event("orchestrator_lost", t, level="WARN", pid=info["pid"], host=info["host"], epoch=view.epoch,
                   tau=int(view.round.tau), rows_on_disk=int(orch.first_row))
    rows = view.rows_from(orch.first_row)
    if orch.first_row < view.round.tau and (not rows or rows[0].tau > orch.first_row):
        first = rows[0].tau if rows else view.round.tau
        orch.rec.event("rows_missing", t, level="WARN", first=int(orch.first_row), last=int(first) - 1,
                       note="the dead orchestrator had not written them and this standby had not followed them")
    orch._execute(rows)
    t_run = None if view.t_run_wall is None else now - (time.time() - float(view.t_run_wall))
    orch._execute(adopt(m, view, info["present"], now, t_run=t_run))
    if orch.takeover is not None and m.finished:  # the run's last round was complete: no tick follows
        took_over(orch, None)


def took_over(orch, tau: int | None) -> None:
    """The first tick of the new orchestrator (``tau``; None: none, the run was over): the takeover's event, with
    the stall since the dead one's last tick."""
    view, info = orch.takeover
    orch.takeover = None
    stall_ms = (time.monotonic() - info["last_tick"]) * 1e3
    t = orch.machine.t(view.round.tau if tau is None else tau)
    fields = {"pid": os.getpid(), "host": socket.gethostname(), "epoch": orch.epoch, "previous_pid": info["pid"],
              "previous_host": info["host"], "stall_ms": round(stall_ms, 1), "tau": int(view.round.tau)}
    orch.rec.event("orchestrator_takeover", t, level="WARN", **fields)
    orch.tally.takeovers = orch.epoch - 1  # epoch 1 started the run; each takeover is one more
    settle_heap(collect=False)  # the records it took on: out of every later collection, with no pause in the catch-up
    log.warning("orchestrator epoch %d (pid %d) took the run over at event time %d from pid %s on %s; rounds "
                "stalled %.0f ms", orch.epoch, os.getpid(), view.round.tau, info["pid"], info["host"], stall_ms)
