"""Deprecated alias of :mod:`.suites.suites_build` (moved in the regroup by subsystem; see ``CHANGELOG.md``).

Import ``v2xbench.envs.v2x_intersection.suites.suites_build`` instead;
this module goes away in the next release.
"""

import warnings as _warnings

from .suites.suites_build import *  # noqa: F403
from .suites.suites_build import __name__ as _target

_warnings.warn(f"{__name__} moved to {_target}; import it from there (this alias goes away in "
               "the next release)", DeprecationWarning, stacklevel=2)


def __getattr__(name: str):
    import importlib

    return getattr(importlib.import_module(_target), name)


if __name__ == "__main__":
    from .suites.suites_build import main

    raise SystemExit(main())
