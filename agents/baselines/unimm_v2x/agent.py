"""The registered agent ``unimm_v2x``: UniMM-V2X's ego half drives, its roadside half is the unit.

``v2xbench eval --agent unimm_v2x --agent-config unimm_v2x.json`` with ``unimm_v2x.json`` =
``{"run": "runs/unimm_v2x"}`` (a run of ``v2xbench baselines train unimm_v2x``). As UniV2X's
agent (:class:`~..univ2x.agent.UniV2XAgent`: ``sensors`` mode, the training data's camera size,
``channel = {"max_payload_floats": F}``, AURORA's waypoint controller), with UniMM-V2X's model,
roadside policy and driver. There are no shipped weights: a run is required.

This module imports nothing heavy: the model loads in the constructor.
"""

from __future__ import annotations

from pathlib import Path

from ..univ2x.agent import UniV2XAgent


class UniMMV2XAgent(UniV2XAgent):
    """UniMM-V2X (Song et al., AAAI 2026) as a driver (module docstring).

    Args:
        run: a trained run folder (``v2xbench baselines train unimm_v2x --out RUN``).
        device: torch device.
    """

    def __init__(self, run: str | None = None, device: str = "cpu") -> None:
        if run is None:
            raise FileNotFoundError('unimm_v2x agent: no run given; pass a trained run with '
                                    '--agent-config FILE holding {"run": "runs/unimm_v2x"} '
                                    '(train one with `v2xbench baselines train unimm_v2x --data '
                                    'DIR --out runs/unimm_v2x`)')
        from .policy import UniMMV2XDriver, UniMMV2XRoadside
        from .train import load_run

        model, cfg, info = load_run(run, device)
        self.run, self.cfg, self.info = str(Path(run)), cfg, info
        size = tuple(int(v) for v in info["camera_size"])
        self.sensors = {"camera_size": size, "camera_images": ("rgb",)}
        self.channel = {"max_payload_floats": cfg.message_floats()}
        self.checkpoint = [info["checkpoint"]]
        self.driver = UniMMV2XDriver(model.ego, cfg, size)
        self.rsu_policy = UniMMV2XRoadside(model.rsu, cfg, size, checkpoint=[info["checkpoint"]])
        self.ticks, self.infer_s = 0, 0.0

    def fingerprint(self) -> str:
        """The scale and the target-speed rule (the weights are in ``checkpoint``)."""
        from v2xbench.agents.aurora.policy import TARGET_SPEED_RULE

        return f"unimm_v2x scale={self.cfg.scale} speed={TARGET_SPEED_RULE}"


__all__ = ["UniMMV2XAgent"]
