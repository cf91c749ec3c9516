"""UniV2X (Yu et al., "End-to-End Autonomous Driving through V2X Cooperation", AAAI 2025), a
CPU-sized variant (docs/baselines.md): camera BEV per agent (Lift-Splat), sparse agent queries +
dense occupancy from the roadside unit, cross-view agent association and fusion, occupancy
fusion, a query-based planner, AURORA's waypoint controller.

Modules: :mod:`.config` (scales), :mod:`.bev` (Lift-Splat, BEV warp, occupancy targets),
:mod:`.message` (the roadside message and its payload), :mod:`.fusion`, :mod:`.planner`,
:mod:`.model`, :mod:`.data`, :mod:`.losses`, :mod:`.train` (training, loading, perception
metrics), :mod:`.policy` (closed loop), :mod:`.agent` (the registered ``univ2x``).
"""
