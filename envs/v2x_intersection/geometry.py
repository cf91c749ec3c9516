"""Deprecated alias of :mod:`.core.geometry` (``CHANGELOG.md``: module moves); goes away in the
next release."""

from ._aliases import forward

forward(globals(), "core.geometry")
