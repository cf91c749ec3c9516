"""Expert data collection, shards, loading (issue #8)."""
