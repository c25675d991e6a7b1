"""Training: the LightningModule, checkpoint I/O, fit(), transfer regimes."""
