"""What an evaluation's results depend on, hashed: the fingerprint ``eval`` keys results by.

An output directory holds the results of one fingerprint (``OUT/run.json``; every result JSON
carries its digest). Its *components* (:func:`make_fingerprint`):

- ``suite``: the suite's name or resolved path;
- ``agent``: the registered name, ``file.py:ClassName`` (the file's name, not its folder), the
  factory's qualified name, or ``policy <Class>``;
- ``agent_code``: SHA-256 of the agent's source files (:func:`code_digests`): the file of a
  ``path/to/file.py:ClassName`` agent (only that file: modules it imports are not followed;
  declare them with ``fingerprint()``); for a built-in agent the modules of ``v2xbench.agents``
  its class is defined in and those they import, transitively (``interface.py``, the harness's
  side, excluded; a baseline's module brings in every module of its method package, which its
  agent loads by name); for another factory the file that defines it;
- ``checkpoint``: SHA-256 of each file or folder the agent declares in ``checkpoint``, and for a
  TorchRL policy passed to ``evaluate`` its architecture and weights (:func:`declared`,
  :func:`policy_digest`); a file inside the installed package (shipped weights) is keyed by its
  path there (``v2xbench/agents/...``: the same key from every clone, :func:`checkpoint_key`),
  any other by the path as declared;
- ``agent_fingerprint``: what the agent's ``fingerprint()`` returns;
- ``agent_config``: the ``--agent-config`` contents (not its path);
- ``config_overrides``: the env overrides (``--set``); ``obs_mode``, ``rsu_policy`` and
  ``action_mode`` as the run uses them; ``agent_process`` (``--isolate-agent`` or not).

The *digest* is the SHA-256 of the components as canonical JSON. :func:`describe_differences`
names what differs between two fingerprints for the refusal message.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import inspect
import json
import sys
from collections.abc import Callable
from os import PathLike
from pathlib import Path
from typing import Any

_CHUNK = 1 << 20
#: module of the harness's side of the interface: not part of any agent's code
_HARNESS_MODULES = frozenset({"v2xbench.agents.interface"})
#: packages whose agents load sibling modules by name (``BaselineAgent._load`` imports the
#: method's ``policy`` and ``train`` with ``importlib``, which the import walk cannot see): a
#: module of ``v2xbench.agents.baselines.<method>`` brings in every module of that package
_WHOLE_PACKAGE_PARENTS = ("v2xbench.agents.baselines",)
#: labels of the components in messages
LABELS = {
    "suite": "suite",
    "agent": "agent",
    "agent_code": "agent code",
    "checkpoint": "checkpoint",
    "agent_fingerprint": "agent fingerprint()",
    "agent_config": "agent config (--agent-config)",
    "config_overrides": "env overrides (--set)",
    "obs_mode": "obs_mode",
    "rsu_policy": "rsu_policy",
    "action_mode": "action_mode",
    "agent_process": "agent_process (--isolate-agent)",
}


def sha256_file(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def sha256_tree(path: str | Path) -> str:
    """SHA-256 (hex) of a folder: every file under it, by relative path and contents."""
    root = Path(path)
    h = hashlib.sha256()
    for p in sorted(q for q in root.rglob("*") if q.is_file()):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + sha256_file(p).encode() + b"\n")
    return h.hexdigest()


def canonical_json(obj: Any) -> str:
    """``obj`` as JSON with sorted keys and no spaces (what digests are computed over)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


# ------------------------------------------------------------------------------ agent code


def _agents_root() -> Path:
    import v2xbench.agents as agents

    return Path(agents.__file__).resolve().parent


def _module_file(name: str) -> Path | None:
    """The source file of module ``v2xbench.agents[.x[.y]]`` (a package's ``__init__.py``)."""
    parts = name.split(".")[2:]
    base = _agents_root().joinpath(*parts)
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if parts and p.is_file():
            return p
    return None


def _imported_agent_modules(name: str, path: Path) -> set[str]:
    """Names of the ``v2xbench.agents`` modules that module ``name`` (file ``path``) imports."""
    is_pkg = path.name == "__init__.py"
    package = name if is_pkg else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                mod = f"{base}.{node.module}" if node.module else base
            else:
                mod = node.module or ""
            found.add(mod)
            found |= {f"{mod}.{a.name}" for a in node.names}  # ``from . import builtin``
    return {m for m in found if m.startswith("v2xbench.agents.") and _module_file(m) is not None}


def _package_siblings(name: str) -> list[str]:
    """Every module of the method package ``name`` belongs to, when that package is one of
    :data:`_WHOLE_PACKAGE_PARENTS`' children (``v2xbench.agents.baselines.univ2x.agent`` ->
    ``...univ2x.model``, ``...univ2x.policy``, ...); else none."""
    for parent in _WHOLE_PACKAGE_PARENTS:
        rest = name[len(parent) + 1:].split(".") if name.startswith(parent + ".") else []
        if len(rest) >= 2:  # a module inside a method package (not the package itself)
            package = f"{parent}.{rest[0]}"
            folder = _module_file(package)
            if folder is None or folder.name != "__init__.py":
                return []
            return [package] + sorted(f"{package}.{p.stem}" for p in folder.parent.glob("*.py")
                                      if p.name != "__init__.py")
    return []


def builtin_code_digests(module: str) -> dict[str, str]:
    """SHA-256 of module ``module`` of ``v2xbench.agents`` and of every module of that package it
    imports, transitively (``interface.py`` excluded), by path relative to the package's parent
    (``agents/expert/planner.py``)."""
    root = _agents_root()
    todo, seen, out = [module], set(), {}
    while todo:
        name = todo.pop()
        if name in seen or name in _HARNESS_MODULES:
            continue
        seen.add(name)
        path = _module_file(name)
        if path is None:
            continue
        out[path.relative_to(root.parent).as_posix()] = sha256_file(path)
        todo.extend(_imported_agent_modules(name, path))
        todo.extend(_package_siblings(name))
    return dict(sorted(out.items()))


def _unwrap(factory: Any) -> Any:
    while isinstance(factory, functools.partial):
        factory = factory.func
    return factory


def factory_code_digests(factory: Callable) -> dict[str, str]:
    """Code digests of an agent factory (module docstring, ``agent_code``)."""
    f = _unwrap(factory)
    module = getattr(f, "__module__", None) or ""
    if module.startswith("v2xbench.agents."):
        return builtin_code_digests(module)
    src = None
    try:
        src = inspect.getsourcefile(f)
    except TypeError:
        pass
    if src is None and module in sys.modules:
        src = getattr(sys.modules[module], "__file__", None)
    return {Path(src).name: sha256_file(src)} if src and Path(src).is_file() else {}


def code_digests(agent: Any) -> dict[str, str]:
    """``agent_code`` of an agent argument: a spec string or a factory (module docstring).

    Raises:
        ValueError: an unknown name or a missing file (``interface.agent_file``).
    """
    from v2xbench.agents.interface import AGENTS, agent_file

    if isinstance(agent, str):
        path = agent_file(agent)
        if path is not None:
            return {path.name: sha256_file(path)}
        return factory_code_digests(AGENTS[agent])
    return factory_code_digests(agent)


def agent_identity(agent: Any) -> str:
    """``agent`` component of an agent argument (module docstring)."""
    if isinstance(agent, str):
        if ":" in agent and agent.rsplit(":", 1)[0].endswith(".py"):
            path, cls = agent.rsplit(":", 1)
            return f"{Path(path).name}:{cls}"
        return agent
    f = _unwrap(agent)
    name = f"{getattr(f, '__module__', '?')}.{getattr(f, '__qualname__', type(f).__name__)}"
    if isinstance(agent, functools.partial):
        name += f"(*{agent.args!r}, **{agent.keywords!r})"
    return name


# ------------------------------------------------------------------------------ declared


def _checkpoint_paths(value: Any, label: str) -> list[str]:
    if value is None:
        return []
    items = list(value) if isinstance(value, (list, tuple)) else [value]
    for p in items:
        if not isinstance(p, (str, PathLike)):
            raise ValueError(
                f"agent {label!r}: checkpoint must be a path or a list of paths, got "
                f"{type(p).__name__} {p!r}"
            )
    return [str(p) for p in items]


#: prefix of the key of a checkpoint inside the installed package (:func:`checkpoint_key`)
PACKAGE_PREFIX = "v2xbench/"


def checkpoint_key(path: str) -> str:
    """The fingerprint's key of a declared checkpoint: ``v2xbench/<path in the package>`` for a
    file or folder inside the installed package (shipped weights: one key whichever folder the
    package is installed or cloned in), otherwise the path as declared."""
    try:
        rel = Path(path).resolve().relative_to(_agents_root().parent)
    except ValueError:
        return path
    return PACKAGE_PREFIX + rel.as_posix()


def _rekey_legacy(old: dict, new: dict) -> dict:
    """``old``'s checkpoint digests re-keyed as :func:`checkpoint_key` keys them in ``new``: a
    path written before (``/some/clone/agents/x``, ``agents/x``) becomes ``v2xbench/agents/x``
    when ``new`` has that key; other keys stay."""
    out = {}
    for k, v in old.items():
        for nk in new:
            rel = nk[len(PACKAGE_PREFIX):]
            if nk.startswith(PACKAGE_PREFIX) and (k == rel or k.endswith("/" + rel)):
                k = nk
                break
        out[k] = v
    return out


def legacy_match(old: dict, new: dict) -> bool:
    """Whether fingerprint components ``old`` (a ``run.json`` written before in-package checkpoints
    were keyed by :func:`checkpoint_key`) describe the same run as ``new``: equal once ``old``'s
    checkpoint paths (absolute, or relative to the clone) are re-keyed, the digests unchanged."""
    if old == new or set(old) != set(new):
        return False
    fixed = dict(old)
    if isinstance(old.get("checkpoint"), dict) and isinstance(new.get("checkpoint"), dict):
        fixed["checkpoint"] = _rekey_legacy(old["checkpoint"], new["checkpoint"])
    ro, rn = old.get("roadside"), new.get("roadside")
    if isinstance(ro, dict) and isinstance(rn, dict) and isinstance(ro.get("checkpoint"), dict) \
            and isinstance(rn.get("checkpoint"), dict):
        fixed["roadside"] = {**ro, "checkpoint": _rekey_legacy(ro["checkpoint"], rn["checkpoint"])}
    return fixed == new


def declared(agent: Any, label: str = "agent") -> dict:
    """What an agent instance declares: ``{"checkpoint": {path: sha256}, "fingerprint": str |
    None}`` (``interface`` module docstring, "Fingerprint").

    Raises:
        ValueError: a checkpoint that is no file or folder, ``fingerprint()`` that raises or
            returns something other than a string.
    """
    ckpt = {}
    for p in _checkpoint_paths(getattr(agent, "checkpoint", None), label):
        path = Path(p)
        if path.is_file():
            ckpt[checkpoint_key(p)] = sha256_file(path)
        elif path.is_dir():
            ckpt[checkpoint_key(p)] = sha256_tree(path)
        else:
            raise ValueError(
                f"agent {label!r} declares checkpoint {p!r}, which is neither a file nor a folder"
            )
    fp = None
    fn = getattr(agent, "fingerprint", None)
    if callable(fn):
        try:
            fp = fn()
        except Exception as e:  # noqa: BLE001  (named in the message)
            raise ValueError(
                f"agent {label!r}: fingerprint() raised {type(e).__name__}: {e}"
            ) from None
        if not isinstance(fp, str):
            raise ValueError(
                f"agent {label!r}: fingerprint() must return a str, got {type(fp).__name__}"
            )
    return {"checkpoint": ckpt, "fingerprint": fp}


def policy_digest(module: Any) -> str:
    """SHA-256 of a TorchRL policy: its architecture (``repr``) and every tensor of its state."""
    import torch

    h = hashlib.sha256(repr(module).encode())
    for k, v in sorted(module.state_dict().items()):
        t = v.detach().cpu().contiguous().reshape(-1)
        h.update(f"\0{k}\0{t.dtype}\0{tuple(v.shape)}\0".encode())
        h.update(t.view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


# ------------------------------------------------------------------------------ fingerprint


def make_fingerprint(components: dict) -> dict:
    """``{"digest": sha256, "components": components}`` (components must be JSON data).

    Raises:
        ValueError: a component is not JSON data (an agent config holding objects, say).
    """
    try:
        text = canonical_json(components)
    except (TypeError, ValueError) as e:
        raise ValueError(
            f"the run's fingerprint needs JSON data (agent config, --set values): {e}"
        ) from None
    return {"digest": hashlib.sha256(text.encode()).hexdigest(), "components": json.loads(text)}


def _short(x: Any, n: int = 120) -> str:
    s = canonical_json(x) if not isinstance(x, str) else repr(x)
    return s if len(s) <= n else s[: n - 3] + "..."


def _dict_diff(old: dict, new: dict) -> list[str]:
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if a == b:
            continue
        if a is None:
            out.append(f"{k} added")
        elif b is None:
            out.append(f"{k} removed")
        else:
            out.append(f"{k} changed (sha256 {a[:12]} -> {b[:12]})")
    return out


def describe_differences(old: dict, new: dict) -> list[str]:
    """What differs between two fingerprints' components, one line per component."""
    lines = []
    for key in sorted(
        set(old) | set(new), key=lambda k: list(LABELS).index(k) if k in LABELS else 99
    ):
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        label = LABELS.get(key, key)
        if key in ("agent_code", "checkpoint") and isinstance(a, dict) and isinstance(b, dict):
            lines.append(f"{label}: {', '.join(_dict_diff(a, b))}")
        else:
            lines.append(f"{label}: {_short(a)} -> {_short(b)}")
    return lines
