"""Data: the Zarr store schema (one reader/writer), generation and ingest into stores, merging,
summaries, training statistics, prior stores (a residual model's windows), the DataModule, and the
industrial robot benchmark's trajectories as its files hold them (``industrial``)."""

# The documented entry point: `from robomorph.data import open_store`.
from robomorph.data.store import open_store  # noqa: E402

__all__ = ["open_store"]
