"""BPTSB training: optimisers with per-parameter learning rates, the trainer loop, checkpoints."""
