"""The package's data files, found wherever the package is: configs, launch files, layouts, the example agent.

The files have one source each in the repository (``config/``, ``launch/``, ``bags/``); the build copies them
into the package, under ``bptsb_ros/share/`` (``setup.py``: :data:`SHARED`), so a wheel installed anywhere
carries them and :mod:`importlib.resources` finds them. Three places are looked at, in this order:

1. the package's own ``share/`` folder (a wheel or sdist install, or ``colcon build``);
2. the source checkout the package was imported from (an editable install, ``PYTHONPATH``): the folder beside
   the ``bptsb_ros`` package, recognised by its ``package.xml``;
3. the ament index (``share/bptsb_ros`` under a sourced ROS workspace or ``AMENT_PREFIX_PATH``), for the
   configs and launch files that ``colcon`` installs there.

Names read from elsewhere are never paths: a packaged name is checked against what is in the folder.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

PACKAGE = "bptsb_ros"

#: the data folders: name inside ``bptsb_ros/share/`` → the repository folder the build copies it from
SHARED: dict[str, str] = {
    "config": "config",
    "launch": "launch",
    "examples/lissajous_agent": "bags/lissajous_agent",
    "examples/lissajous_closed_example": "bags/lissajous_closed_example",
}


class PackageDataError(FileNotFoundError):
    """A data folder of the package is nowhere to be found (a broken install); one line naming where it looked."""


def _installed(kind: str) -> Path | None:
    """``bptsb_ros/share/<kind>`` inside the imported package, if it is a folder on disk."""
    root = importlib.resources.files(PACKAGE) / "share"
    for part in kind.split("/"):
        root = root / part
    return Path(str(root)) if isinstance(root, Path) and root.is_dir() else None


def checkout_root() -> Path | None:
    """The source checkout the package was imported from (the folder holding ``package.xml`` beside the
    ``bptsb_ros`` package), or None for an installed package."""
    root = Path(__file__).resolve().parents[2]  # bptsb_ros/files/package_data.py → the checkout
    manifest = root / "package.xml"
    try:
        if manifest.is_file() and f"<name>{PACKAGE}</name>" in manifest.read_text(encoding="utf-8"):
            return root
    except OSError:
        return None
    return None


def _ament_share(kind: str) -> Path | None:
    """``share/bptsb_ros/<kind>`` found through the ament index, if ament_index_python is there and knows us."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        found = Path(get_package_share_directory(PACKAGE)) / kind
    except (PackageNotFoundError, ValueError):
        return None
    return found if found.is_dir() else None


def data_dir(kind: str) -> Path:
    """The folder of one kind of packaged data (a key of :data:`SHARED`: ``"config"``, ``"launch"``,
    ``"examples/lissajous_agent"`` …); PackageDataError if no place has it."""
    if kind not in SHARED:
        raise ValueError(f"unknown package data {kind!r} (one of {', '.join(SHARED)})")
    found = _installed(kind)
    if found is not None:
        return found
    root = checkout_root()
    if root is not None and (root / SHARED[kind]).is_dir():
        return root / SHARED[kind]
    if not kind.startswith("examples/"):  # colcon installs configs and launch files into the ament share
        found = _ament_share(kind)
        if found is not None:
            return found
    raise PackageDataError(f"the package's {kind} files are missing: not in {PACKAGE}/share/{kind} of the "
                           f"installed package, not in a source checkout, not in the ament index (reinstall "
                           f"{PACKAGE})")


def config_dir() -> Path:
    """The packaged experiment configs and node parameter files (``config/`` of the repository)."""
    return data_dir("config")


def launch_dir() -> Path:
    """The ROS 2 launch files (``launch/<loop>.launch.py``)."""
    return data_dir("launch")


def rviz_config() -> Path:
    """The RViz layout of the live loops (``config/bptsb.rviz``, fixed frame ``msdn``)."""
    return config_dir() / "bptsb.rviz"


def foxglove_layout() -> Path:
    """The Foxglove layout for a recorded bag (``config/foxglove_layout.json``)."""
    return config_dir() / "foxglove_layout.json"


def example_agent() -> Path:
    """The example agent's run directory (``bags/lissajous_agent``: a double-circle body with an SWG brain and its
    fitted feedback layer drawing the Lissajous figure-eight, dt 0.01 s; ``bags/README.md`` says how it was made)."""
    return data_dir("examples/lissajous_agent")


def example_bag() -> Path:
    """The example bag (``bags/lissajous_closed_example``: the example agent's closed loop, recorded live)."""
    return data_dir("examples/lissajous_closed_example")
