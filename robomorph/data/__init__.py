"""Data: the Zarr store schema (one reader/writer), generation and ingest into stores, merging,
summaries, training statistics and the DataModule."""
