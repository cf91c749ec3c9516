"""CoDriving (Liu et al., "Towards Collaborative Autonomous Driving: Simulation Platform and
End-to-End System", IEEE TPAMI 2025), a CPU-sized variant (docs/baselines.md): V2X-ViT's
PointPillars encoder on each agent's LiDAR; driving-oriented communication: the ego's request (a
Gaussian corridor around its route ahead) times the unit's own confidence chooses the roadside
BEV cells to send, within a budget (sparse: cell indices + float16 features); the cells
scattered into the ego grid by ``E_{r->e}`` and max-fused; V2X-ViT's centre-heatmap detection
head and waypoint head; the native controller (a PID on its own waypoints, ours).

Modules: :mod:`.config` (scales, the budget), :mod:`.request` (request map, choice of cells,
the route ahead), :mod:`.message` (the sparse payload), :mod:`.fusion` (scatter into the ego
grid, max fusion), :mod:`.model`, :mod:`.data`, :mod:`.losses`, :mod:`.train` (training,
loading, perception metrics), :mod:`.controller` (the native controller), :mod:`.policy`
(closed loop), :mod:`.agent` (the registered ``codriving``).
"""
