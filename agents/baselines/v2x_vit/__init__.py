"""V2X-ViT (Xu et al., "V2X-ViT: Vehicle-to-Everything Cooperative Perception with Vision
Transformer", ECCV 2022), a CPU-sized variant (docs/baselines.md): a PointPillars encoder on each
agent's LiDAR, the roadside unit's intermediate BEV feature map sent through a learned 1x1
bottleneck (float16 on air), warped into the ego grid by ``E_{r->e}``, a delay-aware positional
encoding of the message's age, V2X-ViT blocks (heterogeneous multi-agent self-attention and
multi-scale window attention), a centre-heatmap BEV detection head, and a simple waypoint head
behind AURORA's waypoint controller (the paper has no planner).

Modules: :mod:`.config` (scales), :mod:`.pillars` (pillarization, pillar encoder, BEV
backbone), :mod:`.message` (the roadside message and its payload), :mod:`.fusion` (delay
encoding, HMSA, MSwin, the V2X-ViT encoder), :mod:`.head` (detection head, targets, decoding,
waypoint head), :mod:`.model`, :mod:`.data`, :mod:`.losses`, :mod:`.train` (training, loading,
perception metrics), :mod:`.policy` (closed loop), :mod:`.agent` (the registered ``v2x_vit``).
"""
