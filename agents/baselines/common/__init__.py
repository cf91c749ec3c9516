"""What the cooperative baselines (:mod:`..univ2x`, :mod:`..unimm_v2x`, :mod:`..v2x_vit`) share:

- :mod:`.config`: the scale table (``for_scale``), ``to_dict`` / ``from_dict`` and the
  validation helpers of their frozen configuration dataclasses;
- :mod:`.train`: the run folder (settings check, training through AURORA's loop, loading, the
  summary line, perception metrics), driven by one :class:`~.train.BaselineRun` per method;
- :mod:`.agent`: the registered agent's constructor and driving loop;
- :mod:`.policy`: the received payload and the planning inputs of a closed-loop observation;
- :mod:`.message`: a payload's float16 rounding and its header check;
- :mod:`.data`, :mod:`.losses`, :mod:`.model`: the planning part of a sample and of the loss, the
  parameter counts.

Nothing heavy is imported here (:mod:`.agent`, :mod:`.config` and :mod:`.train` load torch only
when a model is built or trained).
"""
