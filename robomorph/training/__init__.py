"""Training: the LightningModule, checkpoint I/O, fit(), transfer regimes, and small sequence models
trained on free-run simulation error (``free_run``: ARX, NARX, GRU)."""
