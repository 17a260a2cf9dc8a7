"""The orientation library (the paper's steps 3-4): per frame, the best starting orientations
by R^2 against DDA holograms over a grid of orientations at the frame's prefit position."""
