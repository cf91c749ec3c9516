"""The experiment config: what ``v2xbench experiments run`` runs and ``report`` tabulates.

A config is one JSON (or TOML) object::

    {"name": "paper", "description": "...",
     "defaults": {"device": "cpu", "threads": 1, "workers": 2},
     "methods": {"aurora": {"label": "AURORA", "agent": "aurora"},
                 "univ2x": {"label": "UniV2X", "agent": "univ2x", "baseline": "univ2x"}},
     "jobs": [{"id": "data_train", "kind": "collect", "suite": "train"},
              {"id": "train_aurora", "kind": "aurora_train", "method": "aurora",
               "data": "data_train"},
              {"id": "cl_{method}_lat{latency_ms}", "kind": "closed_loop", "method": "{method}",
               "run": "train_{method}", "channel": {"latency_ms": "{latency_ms}"},
               "matrix": {"method": ["aurora", "univ2x"], "latency_ms": [100, 500]}}],
     "report": {"planning": ["aurora", "univ2x"], "robustness": ["aurora", "univ2x"]}}

``matrix`` expands a job into one job per combination of its values: a string that is exactly
``"{name}"`` becomes the value (its type kept), other strings are formatted with the values.
The fields of each kind are in :data:`KINDS`; ``data``, ``run`` and ``from`` name other jobs
(``needs`` adds more), which makes them dependencies. A method with ``baseline`` is available
only when that name is in ``agents.baselines.BASELINES`` (checked when the run starts): its jobs
are skipped as ``not available`` until then. Every problem raises :class:`ConfigError` naming
the file, the job and the field.
"""

from __future__ import annotations

import itertools
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Kinds of jobs -> their own fields (besides the common ones, :data:`COMMON`).
KINDS: dict[str, tuple[str, ...]] = {
    "collect": ("suite", "seeds", "max_routes", "max_ticks", "camera_size", "lidar_scale",
                "val_fraction", "sensors", "env", "workers", "qa"),
    "dataset": ("path", "qa"),
    "aurora_train": ("data", "scale", "fusion", "from", "planner", "qa", "max_steps", "stride",
                     "seed"),
    "baseline_train": ("data", "scale", "max_steps", "stride", "seed"),
    "shipped": (),
    "perception": ("run", "data", "split", "stride", "top_k", "batch_size", "stage"),
    "open_loop": ("run", "data", "split", "stride", "stage", "batch_size"),
    "closed_loop": ("run", "suite", "seeds", "max_routes", "routes", "scenario", "v2x_only",
                    "workers", "route_timeout", "set", "channel", "agent_config", "stage",
                    "backend", "address"),
    "vqa": ("run", "data", "split", "stride", "stage", "batch_size", "max_new_tokens"),
}
COMMON = ("id", "kind", "method", "needs", "matrix", "label")
#: Fields that name other jobs, and the kinds they may name.
REFS = {"data": ("collect", "dataset"), "run": ("aurora_train", "baseline_train", "shipped"),
        "from": ("aurora_train",)}
#: Kinds that belong to a method (``method`` required).
METHOD_KINDS = ("aurora_train", "baseline_train", "shipped", "perception", "open_loop", "closed_loop",
                "vqa")
CHANNEL_FIELDS = ("latency_ms", "loss_pct", "bandwidth_bytes_per_s")
TABLES = ("perception", "planning", "fusion_ablation", "planner_ablation", "vqa_ablation",
          "per_scenario", "robustness")
DEFAULTS = {"device": "cpu", "threads": 1, "workers": 1}
TICK_MS = 100  # the simulator's tick (EnvConfig.dt = 0.1 s)
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.=-]*$")


class ConfigError(ValueError):
    """A config that cannot run (the message names the file, job and field)."""


@dataclass
class Job:
    """One expanded job of a config."""

    id: str
    kind: str
    spec: dict  # every field as given (after matrix expansion), ``matrix`` removed
    method: str | None = None
    deps: list[str] = field(default_factory=list)

    def get(self, key: str, default: Any = None) -> Any:
        """A field of the job's spec."""
        return self.spec.get(key, default)


@dataclass
class Config:
    """A validated config: methods, jobs in dependency order, report tables."""

    name: str
    description: str
    defaults: dict
    methods: dict[str, dict]
    jobs: list[Job]
    report: dict[str, list[str]]
    source: str
    raw: dict

    def job(self, job_id: str) -> Job:
        """The job of an id (``KeyError`` naming it)."""
        for j in self.jobs:
            if j.id == job_id:
                return j
        raise KeyError(f"no job {job_id!r} in config {self.name!r}")

    def label(self, method: str) -> str:
        """A method's display label."""
        return str(self.methods.get(method, {}).get("label", method))


def load_config(path: str | Path) -> Config:
    """Read and validate a JSON (``.json``) or TOML (``.toml``) config file.

    Raises:
        FileNotFoundError: no such file. ConfigError: it does not parse or does not validate.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"experiment config {str(p)!r} not found")
    text = p.read_text()
    if p.suffix == ".toml":
        try:
            import tomllib
        except ImportError:  # Python 3.10
            raise ConfigError(f"{p}: TOML needs Python >= 3.11 (tomllib); use JSON") from None
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{p}: not valid TOML: {e}") from None
    else:
        try:
            raw = json.loads(text)
        except json.JSONDecodeError as e:
            raise ConfigError(f"{p}: not valid JSON: {e.msg} at line {e.lineno}, column "
                              f"{e.colno}") from None
    return parse_config(raw, str(p))


def _fail(src: str, where: str, msg: str) -> ConfigError:
    return ConfigError(f"{src}: {where}: {msg}")


def _substitute(value: Any, env: dict) -> Any:
    if isinstance(value, str):
        m = re.fullmatch(r"\{(\w+)\}", value)
        if m and m.group(1) in env:
            return env[m.group(1)]
        try:
            return value.format(**env) if env else value
        except (KeyError, IndexError, ValueError):
            return value
    if isinstance(value, dict):
        return {k: _substitute(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [_substitute(v, env) for v in value]
    return value


def _expand(src: str, k: int, entry: Any) -> list[dict]:
    where = f"jobs[{k}]"
    if not isinstance(entry, dict):
        raise _fail(src, where, f"expected an object, got {type(entry).__name__}")
    matrix = entry.get("matrix")
    if matrix is None:
        return [dict(entry)]
    if not isinstance(matrix, dict) or not matrix or not all(
            isinstance(v, list) and v for v in matrix.values()):
        raise _fail(src, f"{where} (id {entry.get('id')!r})", "field 'matrix': expected an "
                    "object of non-empty lists, e.g. {\"latency_ms\": [100, 500]}")
    base = {kk: v for kk, v in entry.items() if kk != "matrix"}
    keys = list(matrix)
    return [_substitute(base, dict(zip(keys, combo)))
            for combo in itertools.product(*(matrix[x] for x in keys))]


def _check_type(src: str, where: str, key: str, value: Any) -> None:
    """The type checks of the fields every kind shares."""
    def bad(want: str) -> ConfigError:
        return _fail(src, where, f"field {key!r}: expected {want}, got {value!r}")

    pos_int = ("seeds", "max_routes", "max_ticks", "max_steps", "stride", "workers", "top_k",
               "batch_size", "max_new_tokens", "stage")
    if key in pos_int and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
        raise bad("an int >= 1")
    if key in ("suite", "path", "split", "scale", "planner", "data", "run", "from", "label",
               "routes") and not (isinstance(value, str) and value):
        raise bad("a non-empty string")
    if key == "backend" and value not in ("local", "ray"):
        raise bad("'local' or 'ray'")
    if key == "address" and not (isinstance(value, str) and value):
        raise bad("a Ray address (HEAD:6379 or auto)")
    if key in ("fusion", "qa", "v2x_only") and not isinstance(value, bool):
        raise bad("true or false")
    if key in ("set", "env", "agent_config", "channel") and not isinstance(value, dict):
        raise bad("an object")
    if key == "needs" and not (isinstance(value, list) and all(isinstance(x, str) for x in value)):
        raise bad("a list of job ids")
    if key == "seed" and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
        raise bad("an int >= 0")
    if key in ("lidar_scale", "val_fraction", "route_timeout") and (
            isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0):
        raise bad("a number > 0")
    if key == "camera_size" and not (isinstance(value, list) and len(value) == 2 and all(
            isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in value)):
        raise bad("[width, height] in pixels")
    if key in ("sensors", "scenario") and not (
            isinstance(value, list) and all(isinstance(x, str) for x in value)):
        raise bad("a list of names")
    if key == "channel":
        _check_channel(src, where, value)


def _check_channel(src: str, where: str, ch: dict) -> None:
    for k, v in ch.items():
        if k not in CHANNEL_FIELDS:
            raise _fail(src, where, f"field 'channel.{k}': unknown; known: {CHANNEL_FIELDS}")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise _fail(src, where, f"field 'channel.{k}': expected a number, got {v!r}")
    lat = ch.get("latency_ms", 0)
    if lat < 0 or lat % TICK_MS:
        raise _fail(src, where, f"field 'channel.latency_ms': {lat!r} must be >= 0 and a "
                    f"multiple of the {TICK_MS} ms tick")
    if not 0 <= ch.get("loss_pct", 0) <= 100:
        raise _fail(src, where, f"field 'channel.loss_pct': {ch['loss_pct']!r} must be in "
                    "[0, 100]")
    if ch.get("bandwidth_bytes_per_s", 1) <= 0:
        raise _fail(src, where, "field 'channel.bandwidth_bytes_per_s': "
                    f"{ch['bandwidth_bytes_per_s']!r} must be > 0")


def channel_overrides(channel: dict | None) -> dict:
    """The ``EnvConfig`` overrides of a job's ``channel`` settings: ``latency_ms`` is the delay
    added to the channel's one-tick minimum (``latency_ticks = 1 + latency_ms / 100``),
    ``loss_pct`` the share of lost messages, ``bandwidth_bytes_per_s`` the cap on air."""
    ch = channel or {}
    out: dict[str, Any] = {}
    if ch.get("latency_ms"):
        out["latency_ticks"] = 1 + int(ch["latency_ms"]) // TICK_MS
    if ch.get("loss_pct"):
        out["loss_prob"] = float(ch["loss_pct"]) / 100.0
    if ch.get("bandwidth_bytes_per_s") is not None:
        out["bandwidth_bytes_per_s"] = float(ch["bandwidth_bytes_per_s"])
    return out


def _check_job(src: str, d: dict, methods: dict) -> Job:
    jid = d.get("id")
    if not isinstance(jid, str) or not _ID.match(jid):
        raise _fail(src, f"job {jid!r}", "field 'id': expected letters, digits and _ . = - "
                    "(after matrix expansion)")
    where = f"job {jid!r}"
    kind = d.get("kind")
    if kind not in KINDS:
        raise _fail(src, where, f"field 'kind': {kind!r} is not one of {sorted(KINDS)}")
    unknown = sorted(set(d) - set(COMMON) - set(KINDS[kind]))
    if unknown:
        raise _fail(src, where, f"unknown field(s) {unknown} for kind {kind!r}; its fields: "
                    f"{sorted(KINDS[kind])} (and {list(COMMON)})")
    for key, value in d.items():
        _check_type(src, where, key, value)
    method = d.get("method")
    if kind in METHOD_KINDS:
        if method not in methods:
            raise _fail(src, where, f"field 'method': {method!r} is not in 'methods' "
                        f"({sorted(methods)})")
    elif method is not None:
        raise _fail(src, where, f"field 'method': a {kind!r} job belongs to no method")
    need = {"collect": ("suite",), "dataset": ("path",), "aurora_train": ("data",),
            "baseline_train": ("data",), "shipped": (), "perception": ("run", "data"),
            "open_loop": ("run", "data"), "closed_loop": ("suite",), "vqa": ("run", "data")}
    for key in need[kind]:
        if key not in d:
            raise _fail(src, where, f"field {key!r} is required for kind {kind!r}")
    if kind == "aurora_train" and "planner" in d and "from" not in d:
        raise _fail(src, where, "field 'planner' needs 'from' (a trained AURORA job whose "
                    "stages 0-2 the planner variant starts from)")
    if kind == "baseline_train" and not methods[method].get("baseline"):
        raise _fail(src, where, f"method {method!r} has no 'baseline' name (methods."
                    f"{method}.baseline)")
    spec = {k: v for k, v in d.items() if k != "matrix"}
    deps = [d[k] for k in REFS if k in d] + list(d.get("needs", []))
    return Job(jid, kind, spec, method, list(dict.fromkeys(deps)))


def _order(src: str, jobs: list[Job]) -> list[Job]:
    """``jobs`` in dependency order (config order where free); refs checked."""
    by_id = {j.id: j for j in jobs}
    for j in jobs:
        for key, kinds in REFS.items():
            ref = j.get(key)
            if ref is None:
                continue
            if ref not in by_id:
                raise _fail(src, f"job {j.id!r}", f"field {key!r}: no job {ref!r} in the config")
            if by_id[ref].kind not in kinds:
                raise _fail(src, f"job {j.id!r}", f"field {key!r}: job {ref!r} is a "
                            f"{by_id[ref].kind!r} job, expected one of {kinds}")
        for ref in j.get("needs", []):
            if ref not in by_id:
                raise _fail(src, f"job {j.id!r}", f"field 'needs': no job {ref!r} in the config")
    done: list[Job] = []
    state: dict[str, int] = {}

    def visit(j: Job, path: list[str]) -> None:
        if state.get(j.id) == 2:
            return
        if state.get(j.id) == 1:
            raise _fail(src, f"job {j.id!r}", f"dependency cycle: {' -> '.join(path + [j.id])}")
        state[j.id] = 1
        for dep in j.deps:
            visit(by_id[dep], path + [j.id])
        state[j.id] = 2
        done.append(j)

    for j in jobs:
        visit(j, [])
    return done


def parse_config(raw: Any, source: str = "<config>") -> Config:
    """Validate a config object (module docstring) and expand its jobs.

    Raises:
        ConfigError: naming the field (and job) that is wrong.
    """
    src = source
    if not isinstance(raw, dict):
        raise ConfigError(f"{src}: expected an object at the top, got {type(raw).__name__}")
    unknown = sorted(set(raw) - {"name", "description", "defaults", "methods", "jobs", "report"})
    if unknown:
        raise _fail(src, "top level", f"unknown field(s) {unknown}")
    name = raw.get("name")
    if not isinstance(name, str) or not name:
        raise _fail(src, "top level", "field 'name': expected a non-empty string")
    defaults = dict(DEFAULTS)
    d = raw.get("defaults", {})
    if not isinstance(d, dict) or set(d) - set(DEFAULTS):
        raise _fail(src, "field 'defaults'", f"expected an object with keys of {list(DEFAULTS)}")
    for k in ("threads", "workers"):
        if k in d and (isinstance(d[k], bool) or not isinstance(d[k], int) or d[k] < 1):
            raise _fail(src, "field 'defaults'", f"{k}={d[k]!r} must be an int >= 1")
    defaults.update(d)
    methods = raw.get("methods", {})
    if not isinstance(methods, dict):
        raise _fail(src, "field 'methods'", "expected an object of method name -> settings")
    for m, s in methods.items():
        if not isinstance(s, dict) or set(s) - {"label", "agent", "baseline", "cooperative"}:
            raise _fail(src, f"methods.{m}", "expected an object with keys of label, agent, "
                        "baseline, cooperative")
    entries = raw.get("jobs")
    if not isinstance(entries, list) or not entries:
        raise _fail(src, "top level", "field 'jobs': expected a non-empty list")
    jobs: list[Job] = []
    seen: dict[str, int] = {}
    for k, entry in enumerate(entries):
        for d in _expand(src, k, entry):
            j = _check_job(src, d, methods)
            if j.id in seen:
                raise _fail(src, f"job {j.id!r}", f"the id repeats (jobs[{seen[j.id]}] and "
                            f"jobs[{k}]; a matrix job's id needs every matrix name)")
            seen[j.id] = k
            jobs.append(j)
    report = raw.get("report", {})
    if not isinstance(report, dict):
        raise _fail(src, "field 'report'", "expected an object of table -> methods")
    for table, ms in report.items():
        if table not in TABLES:
            raise _fail(src, f"report.{table}", f"unknown table; known: {TABLES}")
        if not isinstance(ms, list) or not all(m in methods for m in ms):
            raise _fail(src, f"report.{table}", f"expected a list of methods of 'methods' "
                        f"({sorted(methods)}), got {ms!r}")
    return Config(name, str(raw.get("description", "")), defaults, methods,
                  _order(src, jobs), {k: list(v) for k, v in report.items()}, src, raw)


__all__ = ["CHANNEL_FIELDS", "KINDS", "TABLES", "Config", "ConfigError", "Job",
           "channel_overrides", "load_config", "parse_config"]
