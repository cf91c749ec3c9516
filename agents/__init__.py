"""Driving agents (expert, AURORA, baselines) behind one policy interface."""
