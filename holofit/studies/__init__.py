"""Studies of holofit's accuracy on simulated data with known truth."""
