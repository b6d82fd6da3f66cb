"""Command-line tools around sim_node's bags, without DDS (docs/replay.md, docs/live.md)."""
