"""Data: the Zarr store schema (one reader/writer), training statistics, the DataModule, ingest, merging, summaries."""

from robomorph.data.store import (
    SCHEMA_VERSION,
    Dataset,
    DatasetWriter,
    SchemaError,
    create_store,
    open_store,
)

__all__ = ["SCHEMA_VERSION", "Dataset", "DatasetWriter", "SchemaError", "create_store", "open_store"]
