"""The claim identity of a run: who holds each plant or agent identity, and the process table.

:class:`Claim` is one granted identity (the nonce, pid and host of the process that holds it, and whether its
liveliness token is up); :class:`ClaimTable` keeps every claim of a run and the process table the registry
shows, and holds the rules of a claim: who is granted an identity, who is refused, which liveliness token
counts (the module docstring of :mod:`.machine`, *Identity*).  I/O-free: the times are the machine's ``now``.
"""

from __future__ import annotations

import signal
from dataclasses import dataclass

from .actions import Event, Log, RegistryUpdate, ReplyConfig, ReplyRefused

__all__ = ["Claim", "ClaimTable", "describe_status"]


@dataclass
class Claim:
    """A granted identity: the process (nonce, pid, host) that holds ``role``/``ident``."""
    nonce: str
    pid: int
    host: str
    since: float
    present: bool = False  # its liveliness token is up
    released: bool = False  # token gone, superseded by a restart, or the agent was declared lost

    def live(self, now: float, ttl: float) -> bool:
        return not self.released and (self.present or now - self.since < ttl)


def describe_status(status: int) -> str:
    """``Popen.returncode`` in words: ``exit status 1`` / ``killed by SIGKILL``."""
    if status is None:
        return "still running"
    if status < 0:
        try:
            return f"killed by {signal.Signals(-status).name}"
        except ValueError:
            return f"killed by signal {-status}"
    return f"exit status {status}"


class ClaimTable:
    """Every claim of a run, by identity, and the process table of the granted processes.

    ``agent_ids``: the run's agents; ``wait``: how long a granted claim holds without its token;
    ``plantless``: live sensors, no plant process takes part.
    """

    def __init__(self, agent_ids, *, wait: float, plantless: bool):
        self.agent_ids, self.wait, self.plantless = tuple(agent_ids), float(wait), bool(plantless)
        self._known = set(self.agent_ids)
        self.claims: dict = {}  # (role, ident) -> Claim
        self.procs: dict = {}  # "plant" / agent id -> {"pid", "host"} of the granted process

    @staticmethod
    def key(role: str, ident: int) -> tuple:
        return (role, 0 if role == "plant" else int(ident))

    @staticmethod
    def who(role: str, ident: int) -> str:
        return "the plant" if role == "plant" else f"agent {ident}"

    def get(self, role: str, ident: int) -> Claim | None:
        return self.claims.get(self.key(role, ident))

    def pid(self, name) -> int | None:
        """The pid of the granted process of ``name`` ("plant" or an agent id), or None."""
        return self.procs.get(name, {}).get("pid")

    # ------------------------------------------------------------------ the rules of a claim

    def hello(self, ref, h: dict, now: float, *, started: bool, t: float) -> list:
        """A process claims an identity (``h``: role, id, pid, host, nonce): grant it (reply config) or refuse.

        Granted when nobody holds the identity (never claimed, or the holder's token went away, or the holder
        was declared lost, or it never showed a token within ``wait`` seconds); the same nonce asking again
        gets the same answer; a second claimant of a held identity is refused with the holder's pid and host.
        ``started``: the run is under way (a plant comes too late); ``t``: the event time of the events.
        """
        role, ident = h["role"], int(h["id"])
        who = self.who(role, ident)
        if role not in ("plant", "agent") or (role == "agent" and ident not in self._known):
            return self._refuse(ref, h, t, f"{role} {ident} is not part of this run (agents: "
                                           f"{', '.join(map(str, self.agent_ids))})")
        key = self.key(role, ident)
        c = self.claims.get(key)
        if c is not None and c.nonce == h["nonce"]:
            return [ReplyConfig(ref, role, ident)]  # the same process asking again
        if c is not None and c.live(now, self.wait):
            reason = f"{who} is held by pid {c.pid} on host {c.host}; refusing a second process for it"
            return [
                ReplyRefused(ref, reason, c.pid, c.host),
                Event("duplicate_refused", t, {"role": role, "id": ident, "pid": h["pid"], "host": h["host"],
                                               "holder_pid": c.pid, "holder_host": c.host}),
                Log("warning", f"refused a second process for {who} (pid {h['pid']} on {h['host']}): held by pid "
                               f"{c.pid} on {c.host}")]
        if role == "plant" and self.plantless:
            return self._refuse(ref, h, t, "this run has live sensors (scenario sources:): it takes no plant")
        if role == "plant" and started:
            return self._refuse(ref, h, t, "the run is under way: the plant must be present from event time 0")
        self.claims[key] = Claim(nonce=h["nonce"], pid=int(h["pid"]), host=str(h["host"]), since=now)
        self.procs["plant" if role == "plant" else ident] = {"pid": int(h["pid"]), "host": str(h["host"])}
        return [ReplyConfig(ref, role, ident), RegistryUpdate(),
                Event("process_started", t, {"role": role, "id": ident, "pid": h["pid"], "host": h["host"]})]

    @staticmethod
    def _refuse(ref, h: dict, t: float, reason: str) -> list:
        return [ReplyRefused(ref, reason, 0, ""), Event("identity_refused", t, {
            "role": h["role"], "id": int(h["id"]), "pid": h["pid"], "host": h["host"], "reason": reason})]

    def token(self, role: str, ident: int, nonce: str | None, present: bool) -> Claim | None:
        """A liveliness token appeared or disappeared: the granted claim it changed, or None (an impostor's, a
        superseded process's or a lost agent's token is ignored; only the granted claim's token counts).  A
        token gone releases the claim."""
        c = self.get(role, ident) if role in ("plant", "agent") else None
        if c is None or c.nonce != nonce or (c.released and present):
            return None
        if present:
            c.present = True
            return c
        if c.released:
            return None
        c.present, c.released = False, True
        return c

    def gone(self, role: str, ident: int, pid: int, t: float) -> list:
        """The granted process ``pid`` on this host (not a child) is no longer running, before its token showed:
        the identity is free again; its events (none if ``pid`` does not hold it, or showed its token)."""
        c = self.get(role, ident)
        if c is None or c.pid != pid or c.released or c.present:
            return []
        c.released = True
        return [Event("process_left", t, {"role": role, "id": ident, "pid": pid}),
                Log("warning", f"{self.who(role, ident)} (pid {pid}) exited before it was ready; waiting for "
                               "another one")]

    def exited(self, role: str, ident: int, pid: int) -> bool:
        """The child ``pid`` exited: if it held ``role``/``ident``, its claim is released (True)."""
        c = self.get(role, ident)
        if c is None or c.pid != pid or c.released:
            return False
        c.present, c.released = False, True
        return True

    def release(self, role: str, ident: int) -> None:
        """A new process may claim the identity; the one that held it never counts again."""
        c = self.get(role, ident)
        if c is not None:
            c.released = True

    def adopt(self, procs: dict, present: set, now: float) -> None:
        """A takeover: the granted processes of the active orchestrator's table (``procs``: "plant" / agent id ->
        pid, host, nonce), each present if its token is among ``present`` (``(role, id, nonce)``)."""
        for name, p in procs.items():
            role, ident = ("plant", 0) if name == "plant" else ("agent", int(name))
            up = (role, ident, p["nonce"]) in present
            self.claims[(role, ident)] = Claim(nonce=str(p["nonce"]), pid=int(p["pid"]), host=str(p["host"]),
                                               since=now, present=up)
            self.procs[name] = {"pid": int(p["pid"]), "host": str(p["host"])}

    def state(self) -> dict:
        """The process table with each granted process's nonce (a standby's :meth:`adopt` takes it)."""
        out = {}
        for (role, ident), c in self.claims.items():
            if not c.released:
                out["plant" if role == "plant" else str(ident)] = {"pid": c.pid, "host": c.host, "nonce": c.nonce}
        return out

    def missing(self) -> list:
        """Who does not yet hold a granted claim with its token up ("plant", "agent 3")."""
        out = []
        plant = [(("plant", 0), "plant")] * (not self.plantless)
        for key, who in plant + [(("agent", a), f"agent {a}") for a in self.agent_ids]:
            c = self.claims.get(key)
            if c is None or not c.present or c.released:
                out.append(who)
        return out

    def shift(self, gap: float) -> None:
        """The orchestrator itself was frozen for ``gap`` seconds: nobody's token wait is shortened by it."""
        for c in self.claims.values():
            c.since += gap
