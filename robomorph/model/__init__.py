"""The network: the encoder-decoder transformer, its parameter head, the normalization it carries,
a multi-arm model's channels, and model files (the one reader and writer)."""
