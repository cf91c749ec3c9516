"""Deprecated alias of :mod:`.sim.docgen` (``CHANGELOG.md``: module moves); goes away in the
next release."""

from ._aliases import forward

forward(globals(), "sim.docgen")


if __name__ == "__main__":
    from .sim.docgen import main

    raise SystemExit(main())
