"""Deprecated alias of :mod:`.evaluation.episode` (moved in the regroup by subsystem; see ``CHANGELOG.md``).

Import ``v2xbench.envs.v2x_intersection.evaluation.episode`` instead;
this module goes away in the next release.
"""

import warnings as _warnings

from .evaluation.episode import *  # noqa: F403
from .evaluation.episode import __name__ as _target

_warnings.warn(f"{__name__} moved to {_target}; import it from there (this alias goes away in "
               "the next release)", DeprecationWarning, stacklevel=2)


def __getattr__(name: str):
    import importlib

    return getattr(importlib.import_module(_target), name)
