"""Analysis: body renderings, trajectory animations and plots."""
