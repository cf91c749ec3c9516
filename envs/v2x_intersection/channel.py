"""Deprecated alias of :mod:`.v2x.channel` (``CHANGELOG.md``: module moves); goes away in the
next release."""

from ._aliases import forward

forward(globals(), "v2x.channel")
