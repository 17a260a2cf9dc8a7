"""The DDA fit of every frame (the paper's steps 5-6): an initial pass with every parameter
free on frames spread over the movie (the first ones without a T-matrix), a robust average
of the static parameters, and a final pass with them fixed."""
