"""``--secure``: Zenoh user/password authentication and access control for a run.

One user per process: ``orchestrator``, ``plant``, ``agent-<i>`` and, for a
scenario with live sensors (``sources:``), ``sensor-<i>`` (agent i's sensor,
the user's own process), each with a random password.  :func:`generate` writes, into a private directory
(mode 0700, files 0600):

``users.txt``
    the router's dictionary (``user:password`` per line, Zenoh's
    ``transport/auth/usrpwd/dictionary_file``);
``<user>.cred``
    one line ``user:password`` per process, passed with ``--credentials``
    (never on the command line, where ``ps`` would show it).

The orchestrator's embedded router authenticates every client against the
dictionary (a client without credentials, or with a wrong password, is
refused at connection time) and enforces this access-control policy
(:func:`acl_config`; default deny, on the router's transport faces):

* everybody authenticated may subscribe under ``splitspec/<run>/``, receive
  what is published there, query ``config``, see and query liveliness, and
  ask which runs the router hosts (the liveliness query
  ``splitspec/*/alive/orchestrator/*``, answered with this run's
  orchestrator token only: a process with a wrong ``--run-id`` is told so);
* only ``plant`` may publish ``y/*`` and ``truth``, hold ``alive/plant/**`` and
  answer ``status/plant/**``;
* only ``agent-<i>`` may publish ``z/<i>`` and ``xhat/<i>``, hold
  ``alive/agent/<i>/<nonce>`` and answer ``status/agent/<i>/<nonce>``;
* only ``sensor-<i>`` may publish on agent i's source key
  (``sensors/<key>``, :meth:`Keys.sensor`), and that is all it may do
  (it sees the agents' subscriptions to it, nothing else);
* ``tick``, ``control`` and the ``config`` queryable are the orchestrator's
  own session (the router itself, not subject to the policy); nobody else
  may publish them or serve ``config``.  In a run with a standby
  orchestrator the router is a process of its own and the orchestrators are
  its clients: only the ``orchestrator`` user may then publish ``tick``,
  ``control`` and ``state``, serve ``config``, hold an orchestrator's or a
  standby's token and query statuses.

A denied message is dropped by the router silently; the receivers never see
it.  Zenoh's access control is read when the router opens: the set of
users is fixed for the run (a restarted agent reuses its agent's
credentials).
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from ..errors import ScenarioError, SplitspecError
from .wire import ORCHESTRATORS, Keys

__all__ = ["Credentials", "generate", "read_credentials", "acl_config", "user_of"]

DICTIONARY = "users.txt"


def user_of(role: str, ident: int | None = None) -> str:
    """The Zenoh user name of a process.

    Parameters
    ----------
    role : str
        ``"agent"``, ``"plant"`` or ``"orchestrator"``.
    ident : int, optional
        The agent id (agents only).

    Returns
    -------
    str
        ``agent-<ident>`` for an agent, else ``role``.
    """
    return f"agent-{ident}" if role == "agent" else role


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def read_credentials(path) -> tuple:
    """``(user, password)`` from a ``.cred`` file (one line ``user:password``).

    Parameters
    ----------
    path : str or path-like
        The ``.cred`` file.

    Returns
    -------
    (str, str)

    Raises
    ------
    ScenarioError
        If the file cannot be read or is not one line ``user:password``.
    """
    path = Path(path)
    try:
        line = path.read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise ScenarioError(f"cannot read credentials file {path}: {exc.strerror}") from None
    user, sep, password = line.partition(":")
    if not sep or not user or not password or "\n" in line:
        raise ScenarioError(f"credentials file {path}: expected one line 'user:password'")
    return user, password


def acl_config(run_id: str, agent_ids, sensors: dict | None = None) -> dict:
    """The router's ``access_control`` section for a run (see the module docstring).

    Parameters
    ----------
    run_id : str
        The run id (key prefix ``splitspec/<run_id>``).
    agent_ids : iterable of int
        The scenario's agent ids.
    sensors : dict, optional
        ``{agent id: source key}`` of a scenario's ``sources:`` (relative keys).

    Returns
    -------
    dict
        Zenoh's ``access_control`` config: enabled, default deny, ``rules``, ``subjects``, ``policies``.

    Examples
    --------
    >>> acl = acl_config("r1", [1, 2])
    >>> acl["default_permission"], [s["id"] for s in acl["subjects"]]
    ('deny', ['everyone', 'plant', 'orchestrator', 'agent-1', 'agent-2'])
    """
    keys = Keys(run_id)
    p = keys.prefix

    def rule(rid, messages, flows, keys):
        return {"id": rid, "permission": "allow", "messages": messages, "flows": flows, "key_exprs": keys}

    ingress, egress = ["ingress"], ["egress"]
    rules = [
        # egress too: a declared publisher only sends where it knows of a subscriber (write-side filtering)
        rule("subscribe", ["declare_subscriber"], ["ingress", "egress"], [f"{p}/**"]),
        rule("receive", ["put"], egress, [f"{p}/**"]),
        rule("query-config", ["query"], ["ingress", "egress"], [f"{p}/config"]),
        rule("receive-config", ["reply"], egress, [f"{p}/config"]),
        rule("watch-liveliness", ["declare_liveliness_subscriber", "liveliness_query"], ingress, [f"{p}/alive/**"]),
        rule("see-liveliness", ["liveliness_token"], egress, [f"{p}/alive/**"]),
        # a hand-started process with a wrong --run-id learns which run this router hosts (and says so)
        rule("discover-runs", ["liveliness_query"], ingress, [ORCHESTRATORS]),
        rule("status-query", ["query"], egress, [f"{p}/status/**"]),
        rule("plant-publish", ["put"], ingress, [f"{p}/y/*", f"{p}/truth"]),
        rule("plant-token", ["liveliness_token"], ingress, [f"{p}/alive/plant/**"]),
        rule("plant-status", ["declare_queryable", "reply"], ingress, [f"{p}/status/plant/**"]),
    ]
    # a run with a standby: its orchestrators are clients of the run's own router (not embedded in it)
    rules += [
        rule("orchestrator-publish", ["put"], ingress, [f"{p}/tick", f"{p}/control", f"{p}/state"]),
        rule("orchestrator-config", ["declare_queryable", "reply"], ingress, [f"{p}/config"]),
        rule("orchestrator-token", ["liveliness_token"], ingress, [f"{p}/alive/orchestrator/*",
                                                                   f"{p}/alive/standby/**"]),
        rule("orchestrator-status", ["query"], ingress, [f"{p}/status/**"]),
        rule("orchestrator-answers", ["reply"], egress, [f"{p}/status/**"]),
    ]
    subjects = [{"id": "everyone", "usernames": ["orchestrator", "plant"] + [user_of("agent", i) for i in agent_ids]},
                {"id": "plant", "usernames": ["plant"]}, {"id": "orchestrator", "usernames": ["orchestrator"]}]
    policies = [
        {"id": "everyone", "subjects": ["everyone"],
         "rules": ["subscribe", "receive", "query-config", "receive-config", "watch-liveliness", "see-liveliness",
                   "status-query", "discover-runs"]},
        {"id": "plant", "subjects": ["plant"], "rules": ["plant-publish", "plant-token", "plant-status"]},
        {"id": "orchestrator", "subjects": ["orchestrator"],
         "rules": ["orchestrator-publish", "orchestrator-config", "orchestrator-token", "orchestrator-status",
                   "orchestrator-answers"]},
    ]
    for i in agent_ids:
        u = user_of("agent", i)
        rules += [rule(f"{u}-publish", ["put"], ingress, [f"{p}/z/{i}", f"{p}/xhat/{i}"]),
                  rule(f"{u}-token", ["liveliness_token"], ingress, [f"{p}/alive/agent/{i}/*"]),
                  rule(f"{u}-status", ["declare_queryable", "reply"], ingress, [f"{p}/status/agent/{i}/*"])]
        subjects.append({"id": u, "usernames": [u]})
        policies.append({"id": u, "subjects": [u], "rules": [f"{u}-publish", f"{u}-token", f"{u}-status"]})
    for i, key in (sensors or {}).items():
        u, k = f"sensor-{i}", keys.sensor(key)
        rules += [rule(f"{u}-publish", ["put"], ingress, [k]),
                  rule(f"{u}-interest", ["declare_subscriber"], egress, [k])]
        subjects.append({"id": u, "usernames": [u]})
        policies.append({"id": u, "subjects": [u], "rules": [f"{u}-publish", f"{u}-interest"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


@dataclass(frozen=True)
class Credentials:
    """A credentials directory (see :func:`generate`)."""

    dir: Path
    users: tuple

    @classmethod
    def load(cls, directory) -> "Credentials":
        """Read a credentials directory's ``users.txt``.

        Parameters
        ----------
        directory : str or path-like
            What :func:`generate` wrote into.

        Returns
        -------
        Credentials

        Raises
        ------
        ScenarioError
            If ``users.txt`` cannot be read or a line is not ``user:password``.
        """
        d = Path(directory)
        path = d / DICTIONARY
        try:
            lines = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
        except OSError as exc:
            raise ScenarioError(f"--secure {d}: cannot read {path}: {exc.strerror} (create it with "
                                "`splitspec credentials SCENARIO --out DIR`)") from None
        users = []
        for k, ln in enumerate(lines, 1):
            user, sep, pw = ln.partition(":")
            if not sep or not user or not pw:
                raise ScenarioError(f"{path}:{k}: expected 'user:password'")
            users.append(user)
        return cls(dir=d, users=tuple(users))

    def credentials_file(self, user: str) -> str:
        """Path of a process's ``.cred`` file (whether it exists is not checked).

        Parameters
        ----------
        user : str
            The user (:func:`user_of`).

        Returns
        -------
        str
        """
        return str(self.dir / f"{user}.cred")

    def check_agents(self, agent_ids, sensors: dict | None = None) -> None:
        """Check that the directory holds credentials for the plant, every agent and every live sensor.

        Parameters
        ----------
        agent_ids : iterable of int
            The scenario's agent ids.
        sensors : dict, optional
            ``{agent id: source key}``, as for :func:`acl_config`.

        Raises
        ------
        ScenarioError
            Naming the users without credentials.
        """
        missing = [u for u in ["plant"] + [user_of("agent", i) for i in agent_ids] + [f"sensor-{i}" for i in
                                                                                      (sensors or {})]
                   if u not in self.users]
        if missing:
            raise ScenarioError(f"--secure {self.dir}: no credentials for {', '.join(missing)} (regenerate them "
                                "for this scenario with `splitspec credentials SCENARIO --out DIR`)")

    def router_extra(self, run_id: str, agent_ids, sensors: dict | None = None) -> dict:
        """Extra Zenoh config of the orchestrator's embedded router (``sensors``: as :func:`acl_config`).

        Parameters
        ----------
        run_id : str
            The run id.
        agent_ids : iterable of int
            The scenario's agent ids.
        sensors : dict, optional
            ``{agent id: source key}``.

        Returns
        -------
        dict
            The dictionary file (``transport/auth/usrpwd/dictionary_file``) and ``access_control``.

        Raises
        ------
        ScenarioError
            As :meth:`check_agents`.
        """
        self.check_agents(agent_ids, sensors)
        return {"transport/auth/usrpwd/dictionary_file": str((self.dir / DICTIONARY).resolve()),
                "access_control": acl_config(run_id, agent_ids, sensors)}


def generate(directory, agent_ids, sensor_ids=()) -> Credentials:
    """Write ``users.txt`` and one ``<user>.cred`` per process into ``directory`` (created, mode 0700).

    Parameters
    ----------
    directory : str or path-like
        Where to write (files mode 0600, overwritten).
    agent_ids : iterable of int
        The scenario's agent ids.
    sensor_ids : iterable of int, default ()
        The agents with a live sensor (``sensor-<i>.cred``, for the user's sensor process).

    Returns
    -------
    Credentials
        Users ``orchestrator``, ``plant``, ``agent-<i>``, ``sensor-<i>``, each with a random password.

    Raises
    ------
    SplitspecError
        If the directory or a file cannot be written.
    """
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.chmod(d, 0o700)
        users = ["orchestrator", "plant"] + [user_of("agent", i) for i in agent_ids] + [f"sensor-{i}" for i in
                                                                                       sensor_ids]
        pw = {u: secrets.token_urlsafe(24) for u in users}
        _write_private(d / DICTIONARY, "".join(f"{u}:{pw[u]}\n" for u in users))
        for u in users:
            _write_private(d / f"{u}.cred", f"{u}:{pw[u]}\n")
    except OSError as exc:
        raise SplitspecError(f"cannot write credentials into {d}: {exc.strerror}") from None
    return Credentials(dir=d, users=tuple(users))
