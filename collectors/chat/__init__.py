"""Chat-V2XBench: keyframe facts, QA generation, export and scoring."""
