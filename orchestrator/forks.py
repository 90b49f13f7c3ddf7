"""The orchestrator's side of the agent fork server (:mod:`splitspec_agents.forkserver`).

:class:`ForkServer` starts the server (a child of the orchestrator, with one BLAS thread and
``PR_SET_PDEATHSIG`` like every process it starts) and asks it for agents; each answer is a
:class:`ForkedProcess`, which the orchestrator holds and polls exactly like the ``subprocess.Popen`` of a
spawned process (``pid``, ``poll``, ``returncode``, ``wait``, ``terminate``, ``kill``, ``send_signal``): the
agent is the server's child, so its exit status comes from the server, which reaps it.  When the server
cannot start or stops answering, :meth:`ForkServer.spawn` raises :class:`ForkServerError` and the caller
starts the agent the usual way.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
import time

log = logging.getLogger("splitspec.orchestrator")

#: seconds to wait for the server's first answer (it is importing numpy and Zenoh) and for each fork
READY_TIMEOUT = 60.0
FORK_TIMEOUT = 10.0


class ForkServerError(RuntimeError):
    """The fork server did not start, or stopped answering."""


class ForkServer:
    """A running :mod:`splitspec_agents.forkserver`; :meth:`spawn` forks one agent from it."""

    def __init__(self, *, env: dict, run_id: str):
        from .launcher import spawn

        req_r, self._req_w = os.pipe()
        self._rep_r, rep_w = os.pipe()
        try:
            self.proc = spawn([sys.executable, "-m", "splitspec_agents.forkserver", "--requests", str(req_r),
                               "--replies", str(rep_w), "--run-id", run_id], env=env,
                               pass_fds=(req_r, rep_w))
        finally:
            os.close(req_r)
            os.close(rep_w)
        self.exited: dict = {}  # pid -> Popen-style return code, as the server reports them
        self._answers: queue.SimpleQueue = queue.SimpleQueue()
        self._changed = threading.Condition()
        self._lock = threading.Lock()  # one request at a time: answers come back in order
        self.alive = True
        self.ready = False
        self._reader = threading.Thread(target=self._read, name="fork-server", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        buf = b""
        with open(self._rep_r, "rb", buffering=0) as f:
            while True:
                data = f.read(65536)
                if not data:
                    break
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    msg = json.loads(line)
                    if "exit" in msg:
                        with self._changed:
                            self.exited[int(msg["exit"])] = int(msg["code"])
                            self._changed.notify_all()
                    else:
                        self._answers.put(msg)
        with self._changed:
            self.alive = False
            self._changed.notify_all()
        self._answers.put(None)

    def _answer(self, timeout: float) -> dict:
        try:
            msg = self._answers.get(timeout=timeout)
        except queue.Empty:
            raise ForkServerError(f"the agent fork server did not answer within {timeout:g} s") from None
        if msg is None:
            raise ForkServerError(f"the agent fork server exited ({self.proc.poll()})")
        return msg

    def spawn(self, argv: list) -> "ForkedProcess":
        """Fork an agent running ``python -m splitspec_agents ARGV``; its :class:`ForkedProcess`."""
        with self._lock:
            if not self.alive:
                raise ForkServerError("the agent fork server is not running")
            if not self.ready:
                self._answer(READY_TIMEOUT)  # {"ready": pid}
                self.ready = True
            try:
                os.write(self._req_w, (json.dumps({"argv": [str(a) for a in argv]}) + "\n").encode())
            except OSError as exc:
                raise ForkServerError(f"the agent fork server is gone ({exc.strerror})") from None
            return ForkedProcess(self, int(self._answer(FORK_TIMEOUT)["pid"]))

    def status(self, pid: int) -> int | None:
        """``pid``'s return code once it ended: as the server reported it, or, if the server is gone (its
        children die with it), ``-SIGTERM`` once the process is no longer running."""
        from .registry import pid_running

        with self._changed:
            if pid in self.exited:
                return self.exited[pid]
            if self.alive:
                return None
        return None if pid_running(pid) else -signal.SIGTERM

    def wait_for(self, pid: int, timeout: float | None) -> int | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            code = self.status(pid)
            if code is not None:
                return code
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            with self._changed:
                # the server's exit reports wake this; without the server, poll the pid
                self._changed.wait(0.05 if left is None else min(0.05, left))

    def close(self, *, grace: float = 5.0) -> None:
        """No more agents: the server exits (its remaining children get SIGTERM, PR_SET_PDEATHSIG)."""
        try:
            os.close(self._req_w)
        except OSError:
            pass
        try:
            self.proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout=grace)


class ForkedProcess:
    """An agent forked by the :class:`ForkServer`, with the part of ``subprocess.Popen`` the orchestrator uses."""

    def __init__(self, server: ForkServer, pid: int):
        self.server, self.pid = server, pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self.server.status(self.pid)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            self.returncode = self.server.wait_for(self.pid, timeout)
            if self.returncode is None:
                raise subprocess.TimeoutExpired(f"agent pid {self.pid}", timeout)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)
