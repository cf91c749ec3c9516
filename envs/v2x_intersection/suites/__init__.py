"""Route files and the shipped route suites (``*.json`` in this folder).

:mod:`.route_schema` (every field's type and bounds), :mod:`.route_files` (load, validate,
replay as an episode) and :mod:`.suites_build` (``python -m
v2xbench.envs.v2x_intersection.suites.suites_build`` rebuilds the suites).
"""
