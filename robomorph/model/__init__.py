"""The network: the encoder-decoder transformer and the normalization it carries in checkpoints."""
