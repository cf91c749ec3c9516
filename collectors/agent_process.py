"""Run an agent in its own process, apart from the simulator (``v2xbench eval --isolate-agent``).

:class:`IsolatedAgent` starts ``python -m v2xbench.collectors.agent_process`` (a fresh
interpreter, not a fork: nothing of the simulator's memory is copied into it) and talks to it over
a socket pair. The agent is built in that process from its spec string or picklable factory (with
the ``--agent-config`` keyword arguments), so neither its module's import nor its constructor runs
next to the world; the process answers with what the harness needs to know of it (``obs_mode``,
``rsu_policy``, whether ``act`` takes ``info``, its declared checkpoint and fingerprint:
``agent_fingerprint.declared``). Per route the harness sends ``route_info`` (:func:`reset`) and
then one observation (and the step's ``info``) per tick (:func:`act`); the agent process answers
with the agent's output. An agent that brings its own roadside policy (``roadside.py``) keeps it
in its process too: the harness sees a :class:`RemoteRoadside` that sends the roadside unit's
observation there each tick and gets the message back (as numbers); the policy's ``reset`` runs
with the agent's. The agent never sees the :class:`World`, its actor table
or the scenarios: only what the observation and ``route_info`` hold.

Messages to the agent are pickled (the harness is trusted); answers from the agent are JSON
(``Connection.send_bytes``) of plain numbers and strings, at most :data:`MAX_ANSWER_BYTES`, so a
hostile agent cannot run code in the harness by what it sends back. Floats survive JSON exactly,
so an isolated deterministic agent drives exactly as it does in-process.

An exception of the agent comes back as an :class:`AgentProcessError` naming the agent's
exception, with its traceback; the evaluation records it as a failed route, like an in-process
exception. So does a ``SystemExit`` or ``KeyboardInterrupt`` the agent raises (the process goes
on). An agent that does not answer within ``timeout_s`` or whose process dies is killed and
started afresh at the next route. The agent process ends itself within a second when the process
that started it is gone (``eval_workers.exit_with_parent``), so a killed evaluation worker leaves
no agent process behind, even one stuck in ``act``.
"""

from __future__ import annotations

import json
import pickle
import socket
import subprocess
import sys
import traceback
import weakref
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

MAX_ANSWER_BYTES = 1 << 20  # an answer larger than this is an error (1 MiB)
START_TIMEOUT_S = 120.0  # s for the agent process to import and build the agent
CALL_TIMEOUT_S = 60.0  # s for one reset() or act()


class AgentProcessError(RuntimeError):
    """The isolated agent raised, timed out, answered badly or its process died."""

    def __init__(self, message: str, remote_traceback: str | None = None) -> None:
        super().__init__(message)
        self.remote_traceback = remote_traceback

    def __str__(self) -> str:
        base = super().__str__()
        return base if not self.remote_traceback else f"{base}\n\nagent process traceback:\n{self.remote_traceback}"


def _encode_output(output: Any) -> dict:
    """An agent output as JSON-ready data (the shapes are checked by ``interface.to_control``)."""
    if isinstance(output, dict):
        if "waypoints" not in output:
            raise ValueError("agent output dict must have 'waypoints' ((K, 2) ego frame) and 'speed'")
        wps = np.asarray(output["waypoints"], dtype=np.float64)
        msg = {"waypoints": wps.tolist(), "shape": list(wps.shape)}
        if "speed" in output:
            msg["speed"] = float(output["speed"])
        return msg
    a = np.asarray(output, dtype=np.float64)
    return {"control": a.ravel().tolist(), "shape": list(a.shape)}


def decode_output(msg: dict) -> Any:
    """The agent output an :func:`_encode_output` message stands for."""
    if "waypoints" in msg:
        out = {"waypoints": np.asarray(msg["waypoints"], np.float64).reshape(msg["shape"])}
        if "speed" in msg:
            out["speed"] = float(msg["speed"])
        return out
    return np.asarray(msg["control"], np.float64).reshape(msg["shape"])


def _error(e: BaseException) -> dict:
    return {"ok": False, "error": f"{type(e).__name__}: {e}",
            "traceback": "".join(traceback.format_exception(type(e), e, e.__traceback__))}


def serve(conn: Connection) -> None:
    """The agent process's loop: build the agent, then answer ``reset`` / ``act`` until closed."""
    from v2xbench.agents.interface import (
        act_info_style,
        build_agent,
        call_act,
        complete_agent,
        declared_channel,
        declared_sensors,
        granted_privilege,
        load_agent,
    )

    from .agent_fingerprint import declared
    from .roadside import message_values, policy_label, roadside_component, roadside_runner

    def answer(msg: dict) -> None:
        conn.send_bytes(json.dumps(msg).encode())

    try:
        agent_arg, config = conn.recv()
        if granted_privilege(agent_arg):
            raise ValueError(f"{agent_arg!r} is privileged and cannot run isolated")
        if isinstance(agent_arg, str):
            label = agent_arg
            agent = load_agent(agent_arg, config)
        else:  # a factory: never granted privilege here
            label = getattr(agent_arg, "__name__", repr(agent_arg))
            agent = complete_agent(build_agent(agent_arg, label, config), label, False)
        style = act_info_style(agent)
        roadside = roadside_runner(agent)
        hello = {"ok": True, "obs_mode": str(agent.obs_mode), "rsu_policy": policy_label(agent),
                 "name": type(agent).__name__, "takes_info": style is not None,
                 "declared": declared(agent, label), "roadside": roadside_component(agent),
                 "sensors": declared_sensors(agent, label),
                 "channel": declared_channel(agent, label)}
    except BaseException as e:  # noqa: BLE001  (reported to the harness)
        answer(_error(e))
        return
    answer(hello)
    while True:
        try:
            cmd, arg = conn.recv()
        except (EOFError, OSError):  # the harness is gone
            return
        if cmd == "close":
            return
        try:
            if cmd == "reset":
                agent.reset(arg)
                if roadside is not None:
                    roadside.reset(arg)
                answer({"ok": True})
            elif cmd == "rsu_act" and roadside is not None:
                v = message_values(roadside.policy.act(arg), roadside.label)
                msg = None if v is None else {"values": v[0].tolist(), "format": v[1]}
                answer({"ok": True, "message": msg})
            elif cmd == "act":
                obs, info = arg
                answer({"ok": True, "output": _encode_output(call_act(agent, obs, info, style))})
            else:
                raise ValueError(f"unknown command {cmd!r}")
        except BaseException as e:  # noqa: BLE001  (SystemExit too: the route fails, we go on)
            answer(_error(e))


def _kill(proc: subprocess.Popen, conn: Connection) -> None:
    try:
        conn.close()
    except OSError:
        pass
    if proc.poll() is None:
        proc.kill()
        proc.wait()


class IsolatedAgent:
    """A proxy with the agent interface whose agent runs in a separate process (module docstring).

    Args:
        agent: registered name, ``path/to/file.py:ClassName`` or picklable factory.
        timeout_s: longest wait for one ``reset`` / ``act`` answer.
        config: keyword arguments of the agent's constructor (``--agent-config``).

    Attributes:
        obs_mode, name: the agent's, as its process reported them.
        rsu_policy: the agent's built-in RSU policy name, or a :class:`RemoteRoadside` when the
            agent brings its own roadside policy.
        takes_info: whether the agent's ``act`` takes the step's ``info``.
        declared: its declared checkpoint digests and fingerprint (``agent_fingerprint.declared``).
        sensors: the sensor configuration it declares (``interface.declared_sensors``).
        channel: the channel settings it declares (``interface.declared_channel``).
        roadside: its roadside policy's fingerprint component (``roadside.roadside_component``;
            ``None`` for a built-in policy).

    Raises:
        ValueError: the agent could not be built (unknown, no protocol, declares privileged, a
            config its constructor does not take, a declared checkpoint that does not exist).
    """

    privileged = False

    def __init__(self, agent: str | Any, timeout_s: float = CALL_TIMEOUT_S,
                 config: dict | None = None) -> None:
        from v2xbench.agents.interface import granted_privilege

        if granted_privilege(agent):
            raise ValueError(f"agent {agent!r} is privileged (it reads the simulator through bind(world)) "
                             "and cannot run isolated; evaluate it without --isolate-agent")
        self.agent_arg, self.timeout_s, self.config = agent, float(timeout_s), config
        self._proc: subprocess.Popen | None = None
        self._conn: Connection | None = None
        hello = self._start()
        self.obs_mode, self.rsu_policy, self.name = hello["obs_mode"], hello["rsu_policy"], hello["name"]
        self.takes_info, self.declared = bool(hello["takes_info"]), hello["declared"]
        self.sensors = dict(hello.get("sensors") or {})
        self.channel = dict(hello.get("channel") or {})
        self.roadside = hello.get("roadside")
        if self.roadside is not None:
            self.rsu_policy = RemoteRoadside(self, str(hello["rsu_policy"]))

    @property
    def pid(self) -> int | None:
        """Process id of the running agent process (``None`` when none runs)."""
        return self._proc.pid if self._proc is not None and self._proc.poll() is None else None

    def _start(self) -> dict:
        ours, theirs = socket.socketpair()
        try:
            proc = subprocess.Popen([sys.executable, "-m", __name__, str(theirs.fileno())],
                                    pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
        finally:
            theirs.close()
        conn = Connection(ours.detach())
        self._proc, self._conn = proc, conn
        self._finalizer = weakref.finalize(self, _kill, proc, conn)
        try:
            conn.send((self.agent_arg, self.config))
        except (OSError, pickle.PicklingError, AttributeError, TypeError) as e:
            self.close()
            raise ValueError(f"cannot send agent {self.agent_arg!r} to its process ({e}); give a spec "
                             "string or a top-level class or function") from None
        hello = self._receive(START_TIMEOUT_S, "start")
        if not hello.get("ok"):
            self.close()
            raise ValueError(f"agent {self.agent_arg!r} failed to start in its process: {hello.get('error')}")
        return hello

    def _receive(self, timeout: float, what: str) -> dict:
        conn = self._conn
        try:
            if not conn.poll(timeout):
                self.close()
                raise AgentProcessError(f"agent did not answer {what} within {timeout:g} s (killed)")
            data = conn.recv_bytes(MAX_ANSWER_BYTES)
        except (EOFError, OSError) as e:
            code = None
            if self._proc is not None:
                try:  # the socket closes a moment before the process can be reaped
                    code = self._proc.wait(timeout=2.0)
                except subprocess.TimeoutExpired:
                    pass
            self.close()
            raise AgentProcessError(f"agent process ended during {what} (exit code {code}; {e!r})") from None
        try:
            msg = json.loads(data)
            if not isinstance(msg, dict):
                raise ValueError("not a JSON object")
        except ValueError as e:
            self.close()
            raise AgentProcessError(f"agent process sent a malformed answer to {what} ({e})") from None
        return msg

    def _call(self, cmd: str, arg: Any) -> dict:
        if self._proc is None or self._proc.poll() is not None:
            self._start()
        try:
            self._conn.send((cmd, arg))
        except OSError as e:
            self.close()
            raise AgentProcessError(f"agent process is gone ({e!r})") from None
        msg = self._receive(self.timeout_s, cmd)
        if not msg.get("ok"):
            raise AgentProcessError(str(msg.get("error")), str(msg.get("traceback") or "") or None)
        return msg

    def reset(self, route_info: dict) -> None:
        """Send ``route_info`` to the agent's ``reset``."""
        self._call("reset", route_info)

    def act(self, obs: dict, info: dict | None = None) -> Any:
        """The agent's output for ``obs`` (a control array or a waypoint dict); ``info`` reaches
        the agent when its ``act`` takes it (:attr:`takes_info`)."""
        msg = self._call("act", (obs, info if self.takes_info else None))
        try:
            return decode_output(msg["output"])
        except (KeyError, TypeError, ValueError) as e:
            raise AgentProcessError(f"agent process sent a malformed output ({e})") from None

    def close(self) -> None:
        """Stop the agent process (asks it to exit, kills it if it does not within 2 s)."""
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if proc is None:
            return
        self._finalizer.detach()
        if proc.poll() is None:
            try:
                conn.send(("close", None))
                proc.wait(timeout=2.0)
            except (OSError, subprocess.TimeoutExpired):
                pass
        _kill(proc, conn)


class RemoteRoadside:
    """The roadside policy of an :class:`IsolatedAgent`, which runs in the agent's process: ``act``
    sends the roadside unit's observation there and returns the message (``{"length",
    "payload", "format"}`` or ``None``); its ``reset`` runs there with the agent's.

    Attributes:
        label: its name in results (``custom:<ClassName>``, as the agent's process reported it).
    """

    def __init__(self, agent: IsolatedAgent, label: str) -> None:
        self._agent, self.label = agent, label

    def act(self, rsu_obs: dict) -> dict | None:
        """The policy's message for ``rsu_obs`` (checked again by ``roadside.to_message``)."""
        msg = self._agent._call("rsu_act", rsu_obs).get("message")
        if msg is None:
            return None
        try:
            values = np.asarray(msg["values"], np.float64).reshape(-1)
            return {"length": values.shape[0], "payload": values, "format": int(msg["format"])}
        except (KeyError, TypeError, ValueError) as e:
            raise AgentProcessError(
                f"agent process sent a malformed roadside message ({e})") from None


def _main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m v2xbench.collectors.agent_process FD (started by IsolatedAgent)",
              file=sys.stderr)
        return 2
    from v2xbench.collectors.eval_workers import exit_with_parent

    exit_with_parent()
    conn = Connection(int(argv[0]))
    try:
        serve(conn)
    finally:
        conn.close()
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
