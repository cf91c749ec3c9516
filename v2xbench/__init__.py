"""V2XBench: cooperative (vehicle + roadside unit) closed-loop driving benchmark."""

__version__ = "0.1.0"
