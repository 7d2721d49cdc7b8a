"""rths benchmarks: the commands under ``rths bench`` that measure the project's targets."""
