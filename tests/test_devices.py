"""agents/devices.py: an agent's CPU inputs reach a model on another device, outputs come back."""

from __future__ import annotations

import torch
from v2xbench.agents.devices import module_device, run_on_module, to_device


def test_to_device_moves_every_tensor_of_a_nested_input():
    tree = {"a": torch.zeros(2), "b": [torch.ones(1), (torch.ones(3), 5)], "c": "text"}
    out = to_device(tree, "meta")
    assert out["a"].device.type == "meta" and out["b"][0].device.type == "meta"
    assert isinstance(out["b"][1], tuple) and out["b"][1][0].device.type == "meta"
    assert out["b"][1][1] == 5 and out["c"] == "text"
    assert tree["a"].device.type == "cpu"  # the input is left as it was


def test_run_on_module_calls_the_module_on_its_device():
    seen = []

    class Probe(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.ones(2))

        def forward(self, x, extra):
            seen.append((x.device.type, extra["k"].device.type))
            return {"y": x * self.w}

    probe = Probe()
    assert module_device(probe).type == "cpu"
    out = run_on_module(probe, torch.ones(2), {"k": torch.zeros(1)})
    assert torch.equal(out["y"], torch.ones(2)) and seen == [("cpu", "cpu")]
    probe.to("meta")  # a device other than the inputs': they follow the module
    assert module_device(probe).type == "meta"
    try:
        run_on_module(probe, torch.ones(2), {"k": torch.zeros(1)})
    except (NotImplementedError, RuntimeError):
        pass  # meta tensors cannot come back to the CPU; the call itself saw the device
    assert seen[-1] == ("meta", "meta")
    assert module_device(torch.nn.Module()).type == "cpu"
