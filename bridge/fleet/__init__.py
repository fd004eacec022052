"""The fleet stage: many drives at once (batch work on Dask) and the drive catalogue."""
