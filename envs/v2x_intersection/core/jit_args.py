"""Kernel arguments kept in numba typed lists, so that a call pays numba's dispatch for one list
instead of for every array.

numba types and unboxes each argument of a call from Python: a kernel of 44 arguments, many of
them Python scalars, spent ~4.8 us there against ~1.7 us of work (``ego_obs_kernel``, measured
2026-11-26). :class:`PackedArgs` keeps the arguments that hold for a whole episode (the actor
table's columns, the town's tables) in a typed list of one tuple, and a wrapper kernel takes the
list plus the arguments that change each tick: 6.5 -> 4.1 us a call. Unboxing the list itself
costs ~1.5-2 us, so this pays only for long argument lists: for ``ego_contacts_kernel`` (9
arrays), ``route_monitor_kernel`` (20 arguments) and ``builtin_message_kernel`` (19) the packed
call measured slower (2.2 against 1.7, 2.0 against 1.8, 3.1 against 2.4 us) and they stay plain.
:class:`~.jit_batch.ArgLists` does the same for the worlds of a batch.
"""

from __future__ import annotations

import operator
from collections.abc import Callable

from .jit import HAVE_JIT, _njit

if HAVE_JIT:  # pragma: no branch
    from numba.typed import List
else:  # pragma: no cover
    List = list


@_njit
def new_list(item):  # pragma: no cover
    """A typed list holding ``item`` (its type fixes the list's)."""
    out = List()
    out.append(item)
    return out


@_njit
def list_append(lst, item):  # pragma: no cover
    lst.append(item)


@_njit
def list_set(lst, i, item):  # pragma: no cover
    lst[i] = item


class PackedArgs:
    """A kernel's arguments that hold while the objects of a key do, in a typed list of one tuple
    (numba only): :meth:`get` rebuilds the list when any object of the key is not the one it was
    built for (a reset's new actor table, route or channel)."""

    __slots__ = ("_key", "_list")

    def __init__(self) -> None:
        self._key: tuple = ()
        self._list = None

    def __reduce__(self):
        return PackedArgs, ()  # a copy rebuilds its list on use (typed lists cannot be pickled)

    def get(self, key: tuple, build: Callable[[], tuple]):
        """The typed list for ``key`` (``build()`` gives the tuple when it must be rebuilt)."""
        if self._list is None or len(key) != len(self._key) or not all(map(operator.is_, key, self._key)):
            self._list = new_list(build())
            self._key = key
        return self._list


class ListOf:
    """A typed list holding one item (numba only), rebuilt when :meth:`get` is given another
    object: a one-world kernel's episode arguments, checked by identity each call (cheaper than
    :class:`~.jit_batch.ArgLists`' refresh). ``None`` where a typed list cannot hold the item."""

    __slots__ = ("_item", "_list", "broken")

    def __init__(self) -> None:
        self._item = None
        self._list = None
        self.broken = False

    def __reduce__(self):
        return ListOf, ()  # a copy rebuilds its list on use (typed lists cannot be pickled)

    def get(self, item):
        """The typed list of ``item`` (``None``: it cannot be held; the caller falls back)."""
        if item is not self._item:
            if self.broken:
                return None
            try:
                self._list = new_list(item)
            except Exception:  # noqa: BLE001 - a type a typed list cannot hold: fall back for good
                self.broken, self._list = True, None
                return None
            self._item = item
        return self._list
