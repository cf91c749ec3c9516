"""Deprecated alias of :mod:`.v2x.channel` (moved in the regroup by subsystem; see ``CHANGELOG.md``).

Import ``v2xbench.envs.v2x_intersection.v2x.channel`` instead;
this module goes away in the next release.
"""

import warnings as _warnings

from .v2x.channel import *  # noqa: F403
from .v2x.channel import __name__ as _target

_warnings.warn(f"{__name__} moved to {_target}; import it from there (this alias goes away in "
               "the next release)", DeprecationWarning, stacklevel=2)


def __getattr__(name: str):
    import importlib

    return getattr(importlib.import_module(_target), name)
