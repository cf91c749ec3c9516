"""AURORA (seed paper, section 4): dual-view camera perception, trained from scratch.

Part 1 (issue #32) holds the two perception branches and their training:

- :mod:`.config`: :class:`~.config.AuroraConfig` with the ``tiny``, ``default`` and ``paper``
  scales and the per-stage training hyper-parameters (:class:`~.config.StageHParams`).
- :mod:`.vit`, :mod:`.position`: the ViT encoder and the PETR-style depth-aware 3D position
  embedding of its patches.
- :mod:`.det_decoder`, :mod:`.map_decoder`: DETR-style detection (+ traffic-light head) and
  MapTR-style vectorized map decoders.
- :mod:`.branch`: :class:`~.branch.PerceptionBranch`, one per view (``"ego"`` / ``"rsu"``).
- :mod:`.matching`, :mod:`.losses`: Hungarian matching and the set-prediction criterion.
- :mod:`.trainer`: the training loop every stage and baseline reuses.

Part 2 (issue #33) components:

- :mod:`.cqaf`, :mod:`.fused_heads`: the roadside message, DET-CQAF, MAP-CQAF, semantic fusion,
  the fused detection / map heads and their criterion.
- :mod:`.tokenizer`, :mod:`.prompt`, :mod:`.language`: the BPE tokenizer, the run-time prompt,
  the Llama-architecture LM with LoRA, fused visual tokens and the ``<wp>`` hidden state.
- :mod:`.planners`, :mod:`.planner_losses`: VAE / MLP / diffusion planners and their losses.
"""
