"""Deprecated alias of :mod:`.evaluation.episode` (``CHANGELOG.md``: module moves); goes away in the
next release."""

from ._aliases import forward

forward(globals(), "evaluation.episode")
