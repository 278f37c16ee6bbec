"""Analysis: pure functions of snapshots and recorded series, returning result dataclasses."""
