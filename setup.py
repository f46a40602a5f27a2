"""Packaging for bptsb_ros: an ament_python ROS 2 package that also installs with plain pip.

Two install routes must both serve ``ros2 run bptsb_ros <node>``:

* ``colcon build`` runs ``setup.py install --install-scripts $base/lib/bptsb_ros`` (from setup.cfg), so
  setuptools itself writes the console scripts into ``<prefix>/lib/bptsb_ros``.
* ``pip install`` builds a wheel; pip writes console scripts into ``<prefix>/bin`` only. For that route
  :class:`InstallDataWithNodeWrappers` adds one small executable wrapper per node under
  ``<prefix>/lib/bptsb_ros`` (a wheel data file, from ``scripts/ament_node_wrapper.sh``) that execs the
  console script pip put in ``<prefix>/bin``.

``pip install -e`` (as ``make venv`` does) goes through :class:`EditableWheelWithDataFiles`, which
installs the same data files and wrappers. The wrappers are written only when the console scripts do not
already land in ``lib/bptsb_ros``, so colcon's own scripts are never overwritten, and they are not in the
static ``data_files`` that colcon reads (its ``--symlink-install`` symlinks those itself).

Package data: the configs, launch files, layouts and the example agent and bag have one source each in the
repository (``config/``, ``launch/``, ``bags/``). :class:`BuildPyWithSharedData` copies them into the built
package as ``bptsb_ros/share/...`` (``bptsb_ros.files.package_data.SHARED`` names them), where
``importlib.resources`` finds them after any install; ``data_files`` also puts the configs and launch files
into the ament share, ``<prefix>/share/bptsb_ros``, for ``ros2 launch``.

The version is stated once, in ``package.xml`` (ROS tools read it there); this script reads it from there,
and ``bptsb_ros.__version__`` from the installed distribution's metadata.
"""

from __future__ import annotations

import os
import runpy
import shutil
import stat
import xml.etree.ElementTree as ET
from glob import glob

from setuptools import Distribution, find_packages, setup
from setuptools.command.build_py import build_py as _BuildPy

PACKAGE = "bptsb_ros"
HERE = os.path.dirname(os.path.abspath(__file__))
VERSION = ET.parse(os.path.join(HERE, "package.xml")).getroot().findtext("version").strip()

# Data copied into the package (bptsb_ros/share/<name>), each from one repository folder: a copy of
# bptsb_ros.files.package_data.SHARED (setup.py cannot import the package it builds), with the files to take.
SHARED_DATA = {
    "config": ("config", ("*.yaml", "*.json", "*.rviz")),
    "launch": ("launch", ("*.launch.py",)),
    "examples/lissajous_agent": ("bags/lissajous_agent", ("*",)),
    "examples/lissajous_closed_example": ("bags/lissajous_closed_example", ("*",)),
}

# ROS node executables: name -> module whose ``main(args=None)`` runs the node, from the package's node table
# (bptsb_ros/interface/nodes.py: plain data, read without importing the package), and the executables that run
# several nodes in one process (its PROCESSES: bptsb_composed).
_TABLE = runpy.run_path(os.path.join(HERE, "bptsb_ros", "interface", "nodes.py"))
NODES = {node.name: node.module for node in _TABLE["NODES"]} | _TABLE["PROCESSES"]

# Template of the pip-route wrapper (@NODE@ = node name); it execs <prefix>/bin/<node>, which is where pip puts
# the console script for every install scheme (venv, --prefix, --user, Debian's /usr/local).
WRAPPER_TEMPLATE = os.path.join("scripts", "ament_node_wrapper.sh")


# setuptools' own install_data class (its bundled distutils one; there is no setuptools.command.install_data).
_InstallData = Distribution().get_command_class("install_data")


class InstallDataWithNodeWrappers(_InstallData):
    """``install_data`` that also writes the ament node wrappers when console scripts go elsewhere."""

    def run(self) -> None:
        super().run()
        install_cmd = self.get_finalized_command("install")
        node_dir = os.path.join(self.install_dir, "lib", PACKAGE)
        scripts_dir = install_cmd.install_scripts
        if os.path.normpath(os.path.abspath(scripts_dir)) == os.path.normpath(os.path.abspath(node_dir)):
            return  # colcon route: setuptools already put the real console scripts in lib/bptsb_ros
        self.mkpath(node_dir)
        with open(WRAPPER_TEMPLATE, encoding="utf-8") as handle:
            template = handle.read()
        for name in NODES:
            target = os.path.join(node_dir, name)
            with open(target, "w", encoding="utf-8") as handle:
                handle.write(template.replace("@NODE@", name))
            os.chmod(target, os.stat(target).st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
            self.outfiles.append(target)


class BuildPyWithSharedData(_BuildPy):
    """``build_py`` that also copies :data:`SHARED_DATA` into the built package (``bptsb_ros/share/...``).

    Not in an editable install: there the package is the checkout, whose folders ``bptsb_ros.files.package_data``
    reads directly."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return
        for name, (source, patterns) in SHARED_DATA.items():
            target = os.path.join(self.build_lib, PACKAGE, "share", *name.split("/"))
            files = sorted({f for pattern in patterns for f in glob(os.path.join(source, pattern))
                            if os.path.isfile(f)})
            if not files:
                raise RuntimeError(f"setup.py: no files for {PACKAGE}/share/{name} in {source}/")
            self.mkpath(target)
            for f in files:
                shutil.copyfile(f, os.path.join(target, os.path.basename(f)))

    def get_outputs(self, include_bytecode: bool = True) -> list[str]:
        outputs = list(super().get_outputs(include_bytecode))
        for name, (source, patterns) in SHARED_DATA.items():
            target = os.path.join(self.build_lib, PACKAGE, "share", *name.split("/"))
            outputs += sorted({os.path.join(target, os.path.basename(f)) for pattern in patterns
                               for f in glob(os.path.join(source, pattern)) if os.path.isfile(f)})
        return outputs


CMDCLASS: dict[str, type] = {"install_data": InstallDataWithNodeWrappers, "build_py": BuildPyWithSharedData}

try:
    _EditableWheel = Distribution().get_command_class("editable_wheel")  # setuptools >= 64 (PEP 660)
except Exception:  # older setuptools: pip falls back to `setup.py develop`, which colcon also uses
    _EditableWheel = None

if _EditableWheel is not None:

    class EditableWheelWithDataFiles(_EditableWheel):
        """``editable_wheel`` that installs ``data_files`` as well.

        setuptools skips them in editable installs (pypa/setuptools#3399: it asks the distribution for
        ``has_data``, which does not exist), which would leave the venv without the ament index marker,
        package.xml, launch and config files and the lib/bptsb_ros wrappers.
        """

        def _run_install(self, category: str) -> None:
            super()._run_install(category)
            if category == "data" and self.distribution.has_data_files():
                self.run_command("install_data")  # a no-op if setuptools already ran it

    CMDCLASS["editable_wheel"] = EditableWheelWithDataFiles


# What each kind of use installs (docs/getting-started.md, "Install"). The base is the light route: reading,
# analysing and plotting bags and IPC without torch or numba; training and the experiments add them.
TRAIN = [
    "torch>=2.1",  # install the CPU build first (docs/getting-started.md): a bare `torch` pulls CUDA libraries
    # the compiled body kernel; numba 0.68 supports numpy < 2.6 (installed: numpy 2.4) and installs from a wheel
    "numba>=0.68",
    "scikit-learn",  # MNIST readout and separation analyses of the experiments
    "scipy",  # connected regions of the label maps (scipy.ndimage); scikit-learn depends on it too
]
ROS = [  # a full ROS 2 Jazzy install provides these through apt; without one they come as wheels
    "ros-jazzy-rclpy[fastrtps]",
    "ros-jazzy-common-interfaces",
]
DASK = ["distributed"]  # bptsb sweep / reproduce --scheduler: jobs on a Dask cluster; LocalCluster in the tests
DOCS = [  # make docs: the documentation site, its API reference and the tutorial notebooks
    "mkdocs>=1.6",
    "mkdocs-material>=9.5",
    "mkdocstrings-python>=1.10",
    "mkdocs-jupyter>=0.25",
]
DEV = [
    "pytest>=8",
    "pytest-xdist>=3.5",  # make test runs the suite on 2 processes (tests/conftest.py: a domain per worker)
    "ruff==0.17.6",
    "mcap-ros2-support>=0.5",  # the bag test reads every recorded message with mcap_ros2 as well as rosbags
    "colcon-core",
    "colcon-ros",
    "build",  # the wheel and sdist (python -m build), checked by twine and installed by scripts/check_install.sh
    "twine",
    "nbclient",  # the tests run the tutorial notebooks
    "ipykernel",
]

setup(
    name=PACKAGE,
    version=VERSION,
    description="Backpropagation through soft body (BPTSB): differentiable mass-spring-damper bodies and "
    "their brains, trained offline in torch and run live as ROS 2 nodes recorded to MCAP.",
    long_description=open(os.path.join(HERE, "README.md"), encoding="utf-8").read(),
    long_description_content_type="text/markdown",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["py.typed", "ros/TOPICS.md", "tasks/digit_targets.json", "experiments/settings/*.yaml",
                           "experiments/durations.yaml"]},
    python_requires=">=3.11",
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml") + glob("config/*.json") + glob("config/*.rviz"))),
    ],
    install_requires=[
        "numpy<2.6",
        "pyyaml",
        "pydantic>=2",
        "matplotlib",
        "tqdm",
        "mcap>=1.6",
        # decodes bag messages without ROS (bags.decode); 0.10.8 ships the Jazzy types, and bags.decode calls the
        # typestore's per-type CDR deserialisers (Typestore.get_msgdef), whose signature 0.10.8-0.11 share
        "rosbags>=0.10.8,<0.12",
        "imageio",
        "pillow",
        "threadpoolctl",  # one BLAS/OpenMP thread inside every job of the runner (local and Dask workers)
        "psutil",  # bptsb bench --live: the CPU time of every node process
    ],
    extras_require={
        "train": TRAIN,
        "experiments": TRAIN,  # the same: `bptsb reproduce` trains
        "ros": ROS,
        "dask": DASK,
        "docs": DOCS,
        "dev": DOCS + DEV,
        "all": TRAIN + ROS + DASK,
    },
    zip_safe=False,
    maintainer="bptsb_ros maintainers",
    maintainer_email="maintainers@users.noreply.h-seed-4bd205aa.example",
    license="Apache-2.0",
    classifiers=[
        "Programming Language :: Python :: 3",
        "Operating System :: POSIX :: Linux",
        "Topic :: Scientific/Engineering :: Artificial Intelligence",
    ],
    cmdclass=CMDCLASS,
    entry_points={
        "console_scripts": ["bptsb = bptsb_ros.cli:main"]
        + [f"{name} = {module}:main" for name, module in NODES.items()],
    },
)
