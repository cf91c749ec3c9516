"""Deprecated alias of :mod:`.suites.suites_build` (``CHANGELOG.md``: module moves); goes away in the
next release."""

from ._aliases import forward

forward(globals(), "suites.suites_build")


if __name__ == "__main__":
    from .suites.suites_build import main

    raise SystemExit(main())
