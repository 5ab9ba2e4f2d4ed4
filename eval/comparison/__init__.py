"""The controller comparison, ``python -m eval``: every controller on the same seeded episodes."""
