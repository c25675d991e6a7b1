"""Datasets: the Zarr store schema (``store``), and later the training DataModule."""

from robomorph.data.store import (
    SCHEMA_VERSION,
    Dataset,
    DatasetWriter,
    SchemaError,
    create_store,
    open_store,
)

__all__ = ["SCHEMA_VERSION", "Dataset", "DatasetWriter", "SchemaError", "create_store", "open_store"]
