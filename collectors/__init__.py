"""Closed-loop evaluation, dataset collection and Chat-V2XBench generation."""
