"""Offline simulation of trained agents (open and closed loop) and the trajectory file format."""
