"""Orchestration of rths: the rths command, the graph launcher, the recorder, replay, review."""
