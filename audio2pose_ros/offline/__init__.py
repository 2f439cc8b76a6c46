"""Offline use of a model: synthesis from audio, trajectories, benchmarks."""
