"""Field rules with bounds: one small object per field, shared by the environment config, route
and suite files and reset options.

A rule checks one value and raises ``ValueError`` naming the field's path, the value and the
bound, e.g. ``routes[3].scenarios[1].params.speed: 1000000000.0 is outside [0, 30] m/s``.
Booleans are never numbers here (``True`` is not ``1``), numbers must be finite, and bounds are
inclusive. Tables of rules (``config.FIELD_RULES``, ``route_schema.PARAM_RULES``) keep the checks
declarative: a new field is one new line.
"""

from __future__ import annotations

import difflib
import math
import numbers
import re
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any


def _number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def _integer(v: Any) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def kind_of(v: Any) -> str:
    """The JSON-ish type name of ``v`` for messages (``null`` for ``None``)."""
    return "null" if v is None else type(v).__name__


def show(v: Any) -> str:
    """``repr(v)`` for messages, cut to 60 characters."""
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


class Rule:
    """A check of one value (override :meth:`check`)."""

    def check(self, value: Any, path: str) -> None:
        """Raise ``ValueError`` (``"{path}: ..."``) unless ``value`` satisfies the rule."""
        raise NotImplementedError


@dataclass(frozen=True)
class Int(Rule):
    """An integer (not a bool) in ``[lo, hi]``; ``unit`` and ``why`` extend the message."""

    lo: int
    hi: int
    unit: str = ""
    why: str = ""

    def check(self, value: Any, path: str) -> None:
        if not _integer(value):
            raise ValueError(f"{path}: expected an int, got {kind_of(value)} {show(value)}")
        if not self.lo <= value <= self.hi:
            why = f" ({self.why})" if self.why else ""
            raise ValueError(
                f"{path}: {show(value)} is outside [{self.lo}, {self.hi}]{_unit(self.unit)}{why}"
            )


@dataclass(frozen=True)
class Float(Rule):
    """A finite number (an int is fine, a bool is not) in ``[lo, hi]`` (``(lo, hi]`` with
    ``lo_open``)."""

    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False
    why: str = ""

    def check(self, value: Any, path: str) -> None:
        if not _number(value):
            raise ValueError(f"{path}: expected a number, got {kind_of(value)} {show(value)}")
        if not math.isfinite(value):
            raise ValueError(f"{path}: {show(value)} is not a finite number")
        low_ok = value > self.lo if self.lo_open else value >= self.lo
        if not (low_ok and value <= self.hi):
            why = f" ({self.why})" if self.why else ""
            raise ValueError(
                f"{path}: {show(value)} is outside {self._interval()}{_unit(self.unit)}{why}"
            )

    def _interval(self) -> str:
        return f"{'(' if self.lo_open else '['}{_g(self.lo)}, {_g(self.hi)}]"


@dataclass(frozen=True)
class Bool(Rule):
    """``True`` or ``False`` (not ``'no'``, not ``0``)."""

    def check(self, value: Any, path: str) -> None:
        if not isinstance(value, bool):
            raise ValueError(f"{path}: expected true or false, got {kind_of(value)} {show(value)}")


@dataclass(frozen=True)
class Choice(Rule):
    """One of ``choices`` (compared with ``==``; the value's type must match the choice's)."""

    choices: tuple
    why: str = ""

    def check(self, value: Any, path: str) -> None:
        if _number(value):  # -1 and -1.0 are the same number; True is not 1
            ok = any(_number(c) and value == c for c in self.choices)
        else:
            ok = any(type(value) is type(c) and value == c for c in self.choices)
        if not ok:
            why = f" ({self.why})" if self.why else ""
            hint = ""
            if isinstance(value, str):
                close = difflib.get_close_matches(
                    value, [c for c in self.choices if isinstance(c, str)], n=1
                )
                hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(
                f"{path}: {show(value)} is not one of {_listing(self.choices)}{hint}{why}"
            )


@dataclass(frozen=True)
class Text(Rule):
    """A string of ``1..max_len`` characters matching ``pattern`` (``re.fullmatch``) if given."""

    max_len: int = 200
    pattern: str = ""
    what: str = ""

    def check(self, value: Any, path: str) -> None:
        if not isinstance(value, str):
            raise ValueError(f"{path}: expected a string, got {kind_of(value)} {show(value)}")
        if not 1 <= len(value) <= self.max_len:
            raise ValueError(f"{path}: {_short(value)} must have 1 to {self.max_len} characters")
        if self.pattern and not re.fullmatch(self.pattern, value):
            raise ValueError(
                f"{path}: {_short(value)} must be {self.what or 'of the form ' + self.pattern}"
            )


@dataclass(frozen=True)
class Check(Rule):
    """A rule given as a function ``fn(value)`` that raises ``ValueError`` (its message is
    prefixed with the path); ``what`` describes the accepted values."""

    fn: Callable[[Any], None]
    what: str

    def check(self, value: Any, path: str) -> None:
        try:
            self.fn(value)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None


@dataclass(frozen=True)
class OrNone(Rule):
    """``None`` or a value satisfying ``rule``."""

    rule: Rule

    def check(self, value: Any, path: str) -> None:
        if value is not None:
            self.rule.check(value, path)


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _g(x: float) -> str:
    """A bound as written by hand: ``30`` rather than ``30.0``, ``1e+12`` for huge ones."""
    return f"{x:g}" if isinstance(x, float) else str(x)


def _short(s: str, n: int = 60) -> str:
    return repr(s if len(s) <= n else s[:n] + "...")


def _listing(choices: Iterable) -> str:
    return "(" + ", ".join(repr(c) for c in choices) + ")"


def check_keys(d: dict, known: Iterable[str], path: str, required: Iterable[str] = ()) -> None:
    """Raise ``ValueError`` for a key of ``d`` outside ``known`` (with a close match) or a missing
    ``required`` key. ``path``: the dict's own path (``""`` at the top)."""
    known = list(known)
    for key in d:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(
                f"{join(path, str(key))}: unknown field{hint} (known: {', '.join(known)})"
            )
    for key in required:
        if key not in d:
            raise ValueError(f"{join(path, key)}: missing required field")


def check_options(options: Any, known: Iterable[str], where: str = "reset") -> dict:
    """``options`` of a ``reset`` as a dict (``None``: empty); raises ``ValueError`` for a non-dict
    or an unknown key (``where`` names the call in the message)."""
    if options is None:
        return {}
    known = list(known)
    if not isinstance(options, dict):
        raise ValueError(f"{where}: options must be a dict, got {kind_of(options)}")
    for key in options:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            takes = f"known: {', '.join(known)}" if known else "it takes none"
            raise ValueError(f"{where}: unknown option {key!r}{hint} ({takes})")
    return options


def join(path: str, key: str) -> str:
    """``path.key`` (``key`` at the top level)."""
    return f"{path}.{key}" if path else key


class ShortfallWarning(UserWarning):
    """The world delivers less than the config asks (fewer actors fit, a shorter route)."""


_WARNED: set = set()


def warn_once(
    key: tuple, message: str, category: type[Warning] = UserWarning, stacklevel: int = 3
) -> bool:
    """Emit ``message`` once per process for ``key`` (a warning with numbers in it would otherwise
    repeat on every reset); returns whether it was emitted."""
    if key in _WARNED:
        return False
    _WARNED.add(key)
    warnings.warn(message, category, stacklevel=stacklevel)
    return True


def reset_warned() -> None:
    """Forget which warnings :func:`warn_once` has emitted (for tests)."""
    _WARNED.clear()
