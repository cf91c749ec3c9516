"""Perception: what the ego and the active roadside units see (2.5D occlusion, step 7 of a tick).

:mod:`.visibility` (visible fractions from :mod:`..core.raycast`) is the reference and the
fallback without numba; :mod:`.jit_perception` is its kernel twin (the whole step in one call:
active-unit selection, ego and RSU visibility, object rows), tested against it bit for bit.
:mod:`.objects` turns what is seen into object lists in an observer's frame.
"""
