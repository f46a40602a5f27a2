"""bptsb_ros: backpropagation through soft body (BPTSB) — differentiable mass-spring-damper bodies and their
brains, trained offline in torch and run live as ROS 2 nodes recorded to MCAP bags.

The version follows semantic versioning: the minor number grows with each round of new experiments or
interfaces, the patch number with fixes only; every release has its section in CHANGELOG.md. The same
version is stated in ``setup.py`` and ``package.xml`` (a test keeps the three equal).
"""

__version__ = "0.2.0"
