"""Small simulators that produce ``Recording`` objects for the reproductions."""
