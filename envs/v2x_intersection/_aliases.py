"""Deprecated aliases: old module paths that forward to the modules' new homes for one release.

Each alias module (listed in ``DEPRECATED_ALIASES`` of the package) is two lines that call
:func:`forward`; ``CHANGELOG.md`` lists every move.
"""

from __future__ import annotations

import importlib
import warnings


def forward(alias: dict, target: str) -> None:
    """Make the module whose globals are ``alias`` a deprecated alias of ``target`` (a module
    path relative to this package): warn on import (``DeprecationWarning``), copy the target's
    public names, and forward every other name to it on use."""
    module = importlib.import_module(f"{__package__}.{target}")
    warnings.warn(f"{alias['__name__']} moved to {module.__name__}; import it from there "
                  "(this alias goes away in the next release)", DeprecationWarning, stacklevel=3)
    alias.update({k: v for k, v in vars(module).items() if not k.startswith("_")})
    alias["__getattr__"] = lambda name: getattr(module, name)
