"""The live view of a running RTHS: a Foxglove WebSocket server (optional dependency)."""
