"""Orchestration of rths: the rths command-line tool, the launcher of the node graph, the bag recorder and bag tools, replay and review."""
