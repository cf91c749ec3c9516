"""Deprecated alias of :mod:`.evaluation.infractions` (moved in the regroup by subsystem; see ``CHANGELOG.md``).

Import ``v2xbench.envs.v2x_intersection.evaluation.infractions`` instead;
this module goes away in the next release.
"""

import warnings as _warnings

from .evaluation.infractions import *  # noqa: F403
from .evaluation.infractions import __name__ as _target

_warnings.warn(f"{__name__} moved to {_target}; import it from there (this alias goes away in "
               "the next release)", DeprecationWarning, stacklevel=2)


def __getattr__(name: str):
    import importlib

    return getattr(importlib.import_module(_target), name)
