"""Data sets the experiments read (MNIST)."""
