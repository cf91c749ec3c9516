"""UniMM-V2X (Song et al., "UniMM-V2X: MoE-Enhanced Multi-Level Fusion for End-to-End Cooperative
Autonomous Driving", AAAI 2026), a CPU-sized variant (docs/baselines.md): UniV2X's camera BEV,
agent queries, occupancy and fusion (imported from :mod:`..univ2x`), plus Mixture-of-Experts
layers in the BEV encoder and the motion decoder, a motion head, and multi-level cooperation:
the roadside unit sends perception *and* prediction (motion) queries, fused into the ego's.

Modules: :mod:`.config` (scales), :mod:`.moe` (router, experts, balance loss), :mod:`.motion`
(MotionMoE decoder, prediction-level fusion), :mod:`.message`, :mod:`.model`, :mod:`.data`
(motion targets from the data set's future frames), :mod:`.losses`, :mod:`.train`,
:mod:`.policy`, :mod:`.agent` (the registered ``unimm_v2x``).
"""
