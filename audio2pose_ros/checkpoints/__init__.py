"""Checkpoints: the file format, saving/loading torch models, and the torch-free runtime."""
