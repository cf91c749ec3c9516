"""Environments shipped with V2XBench."""
