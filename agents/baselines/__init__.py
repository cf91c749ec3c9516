"""The paper's cooperative baselines (issue #34), each a CPU-sized variant of the published
architecture, trained on the same expert data with AURORA's loop (:mod:`..aurora.trainer`) and
driving behind the same agent interface, its roadside half as the ``"rsu"`` agent:

- :mod:`.codriving`: CoDriving (Liu et al., IEEE TPAMI 2025), registered as ``codriving``.
- :mod:`.univ2x`: UniV2X (Yu et al., AAAI 2025), registered as ``univ2x``.
- :mod:`.unimm_v2x`: UniMM-V2X (Song et al., AAAI 2026), registered as ``unimm_v2x``.
- :mod:`.v2x_vit`: V2X-ViT (Xu et al., ECCV 2022), registered as ``v2x_vit``.

Nothing heavy is imported here: each baseline's agent module loads torch in its constructor.
"""

#: Baselines with a training command (``v2xbench baselines train NAME``): name -> module.
BASELINES = {"codriving": "v2xbench.agents.baselines.codriving",
             "univ2x": "v2xbench.agents.baselines.univ2x",
             "unimm_v2x": "v2xbench.agents.baselines.unimm_v2x",
             "v2x_vit": "v2xbench.agents.baselines.v2x_vit"}

__all__ = ["BASELINES"]
