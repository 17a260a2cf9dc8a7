"""Synthetic data with known truth: hologram movies and Brownian trajectories."""
