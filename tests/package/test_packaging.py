"""The package installs the ament way under both routes: ``colcon build`` and ``pip install`` into a venv.

``ros2 run bptsb_ros <node>`` needs ``<prefix>/lib/bptsb_ros/<node>`` (executable), the package marker in
``<prefix>/share/ament_index/resource_index/packages/`` and ``<prefix>/share/bptsb_ros/package.xml``;
``ros2 launch`` needs ``share/bptsb_ros/launch/*.launch.py``; nodes read ``share/bptsb_ros/config/*.yaml``.
"""

from __future__ import annotations

import filecmp
import importlib.metadata
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from conftest import REPO_ROOT

PACKAGE = "bptsb_ros"
NODES = ("body_sim", "swg_brain", "mlp_brain", "feedback_brain", "task_input", "recorder", "wind_source",
         "image_streamer", "mnist_brain")
#: what lib/bptsb_ros holds: the nodes and the process that runs a loop's nodes together (composed:=true)
EXECUTABLES = (*NODES, "bptsb_composed")
# Top-level entries of the checkout that are not part of the package source.
NOT_SOURCE = {".git", ".venv", ".ci", "build", "install", "log", "runs", "tests", "dist", "site", "reproduction",
              ".pytest_cache", ".ruff_cache", "bench.json"}


def _source_files(pattern: str) -> set[str]:
    return {p.name for p in REPO_ROOT.glob(pattern)}


def _ignore_non_source(directory: str, names: list[str]) -> set[str]:
    ignored = {n for n in names if n == "__pycache__" or n.endswith(".egg-info")}
    if Path(directory).resolve() == REPO_ROOT:
        ignored |= NOT_SOURCE.intersection(names)
    return ignored


def _assert_ament_tree(prefix: Path, *, executables: tuple[str, ...]) -> None:
    """Assert the ament layout under ``prefix`` matches the source tree."""
    for name in executables:
        exe = prefix / "lib" / PACKAGE / name
        assert exe.is_file(), f"missing executable {exe}"
        assert os.access(exe, os.X_OK), f"{exe} is not executable (mode {exe.stat().st_mode:o})"
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    assert marker.is_file(), f"missing ament index marker {marker}"
    share = prefix / "share" / PACKAGE
    assert filecmp.cmp(share / "package.xml", REPO_ROOT / "package.xml", shallow=False), (
        f"{share / 'package.xml'} differs from the source package.xml (reinstall: make venv)"
    )
    for subdir, pattern in (("launch", "*.launch.py"), ("config", "*.yaml"), ("config", "*.rviz")):
        expected = _source_files(f"{subdir}/{pattern}")
        assert expected, f"the source tree has no {subdir}/{pattern}"
        installed = {p.name for p in (share / subdir).glob(pattern)}
        assert installed == expected, f"{share / subdir}: installed {sorted(installed)}, source {sorted(expected)}"


def _package_files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts}


def _wrapper_text(node: str) -> str:
    return (REPO_ROOT / "scripts" / "ament_node_wrapper.sh").read_text().replace("@NODE@", node)


def _package_prefix_from_index(ament_prefix_path: Path) -> str:
    """Resolve bptsb_ros through ament_index_python in a clean subprocess with only ``ament_prefix_path``."""
    env = dict(os.environ, AMENT_PREFIX_PATH=str(ament_prefix_path))
    code = "from ament_index_python import get_package_prefix; print(get_package_prefix('bptsb_ros'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.skipif(importlib.util.find_spec("colcon_core") is None,
                    reason="colcon-core is not installed (it comes with: pip install -e '.[dev]')")
def test_colcon_build_produces_the_ament_install_tree(tmp_path: Path) -> None:
    src = tmp_path / "ws" / "src" / PACKAGE
    shutil.copytree(REPO_ROOT, src, ignore=_ignore_non_source)
    ws = tmp_path / "ws"
    colcon = [sys.executable, "-m", "colcon"] if not (Path(sys.executable).parent / "colcon").exists() \
        else [str(Path(sys.executable).parent / "colcon")]
    env = dict(os.environ, COLCON_HOME=str(tmp_path / "colcon_home"))
    env.pop("COLCON_PREFIX_PATH", None)
    result = subprocess.run(
        [*colcon, "--log-base", str(ws / "log"), "build", "--base-paths", str(ws / "src"),
         "--build-base", str(ws / "build"), "--install-base", str(ws / "install"),
         "--event-handlers", "console_direct-"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, f"colcon build failed:\n{result.stdout}\n{result.stderr}"

    prefix = ws / "install" / PACKAGE
    _assert_ament_tree(prefix, executables=(*EXECUTABLES, "bptsb"))
    for name in (*EXECUTABLES, "bptsb"):
        first_line = (prefix / "lib" / PACKAGE / name).read_text().splitlines()[0]
        assert first_line.startswith("#!") and "python" in first_line, (
            f"colcon should install the setuptools console script for {name}, found {first_line!r}"
        )
    site = [p for p in prefix.glob(f"lib*/python3*/*-packages/{PACKAGE}") if (p / "cli" / "__init__.py").is_file()]
    assert len(site) == 1, f"expected the python package once under {prefix}/lib/python3.*/, found {site}"
    source_files = _package_files(REPO_ROOT / PACKAGE)
    missing = sorted(source_files - _package_files(site[0]))
    assert not missing, f"not installed (a directory without __init__.py, or data missing from setup.py): {missing}"
    assert _package_prefix_from_index(prefix) == str(prefix)

    run_env = dict(os.environ, PYTHONPATH=str(site[0].parent))
    help_run = subprocess.run([str(prefix / "lib" / PACKAGE / "bptsb"), "--help"], env=run_env,
                              capture_output=True, text=True, timeout=60)
    assert help_run.returncode == 0, help_run.stderr
    assert "usage: bptsb" in help_run.stdout


@pytest.mark.ros
def test_pip_install_registers_the_package_under_the_venv_prefix() -> None:
    if sys.prefix == sys.base_prefix:
        pytest.skip("not running from a virtual environment (make venv creates .venv)")
    site_packages = sysconfig.get_paths()["purelib"]
    if not any(d.metadata["Name"] == PACKAGE for d in importlib.metadata.distributions(path=[site_packages])):
        pytest.skip(f"{PACKAGE} is not pip-installed in {sys.prefix} (make venv installs it)")
    prefix = Path(sys.prefix)
    _assert_ament_tree(prefix, executables=EXECUTABLES)
    for name in EXECUTABLES:
        assert (prefix / "lib" / PACKAGE / name).read_text() == _wrapper_text(name)
        console_script = prefix / "bin" / name
        assert console_script.is_file() and os.access(console_script, os.X_OK), f"missing {console_script}"
    assert _package_prefix_from_index(prefix) == str(prefix)


def test_the_version_is_stated_once_in_package_xml() -> None:
    """package.xml holds the version (ROS tools read it there); setup.py reads it from there and states no other,
    ``bptsb_ros.__version__`` and the installed metadata are the same."""
    import re
    import xml.etree.ElementTree as ET

    manifest = ET.parse(REPO_ROOT / "package.xml").getroot()
    assert manifest.get("format") == "3"
    assert manifest.findtext("name") == PACKAGE
    assert manifest.findtext("export/build_type") == "ament_python"
    version = manifest.findtext("version")
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)
    for path in ("setup.py", f"{PACKAGE}/__init__.py", "setup.cfg", "pyproject.toml"):
        text = (REPO_ROOT / path).read_text()
        assert version not in text, f"{path} states the version {version} itself"
    setup_text = (REPO_ROOT / "setup.py").read_text()
    assert "version=VERSION" in setup_text and 'findtext("version")' in setup_text
    import bptsb_ros

    assert bptsb_ros.__version__ == version
    assert importlib.metadata.version(PACKAGE) == version, "the installed metadata is stale (make venv)"
    assert '"interface", "nodes.py"' in setup_text  # its node entry points come from the node table
    scripts = {e.name: e.value for e in importlib.metadata.distribution(PACKAGE).entry_points
               if e.group == "console_scripts"}
    for node in NODES:
        assert scripts.get(node) == f"bptsb_ros.ros.{node}:main", f"{node} is not an entry point of the package"
    assert scripts.get("bptsb_composed") == "bptsb_ros.ros.composed:main"


#: rosdep keys (rosdistro rosdep/python.yaml) of the Python modules the package imports; None: rosdistro has no
#: key, so package.xml must name the distribution in a comment (a pip requirement). Every other third-party
#: import is a ROS package, whose Python package carries its name (rclpy, sensor_msgs, launch_ros, ...).
ROSDEP_KEYS: dict[str, str | None] = {
    "numpy": "python3-numpy", "yaml": "python3-yaml", "pydantic": "python3-pydantic",
    "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm", "PIL": "python3-pil", "numba": "python3-numba",
    "sklearn": "python3-sklearn", "scipy": "python3-scipy", "torch": None, "mcap": None, "distributed": None,
    "rosbags": None,
    "threadpoolctl": None, "psutil": "python3-psutil",
}


def _third_party_imports() -> set[str]:
    """Top-level names of every absolute import in bptsb_ros/ (module level or inside functions), less the
    standard library and the package itself."""
    import ast

    names: set[str] = set()
    for path in (REPO_ROOT / PACKAGE).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {PACKAGE}


def _canonical(name: str) -> str:
    import re

    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_lists() -> dict[str, list[str]]:
    """setup.py's requirement lists, read from its syntax tree: ``install_requires`` and each module-level list
    (TRAIN, ROS, DASK, DOCS, DEV) the extras are made of."""
    import ast

    lists: dict[str, list[str]] = {}
    for node in ast.walk(ast.parse((REPO_ROOT / "setup.py").read_text())):
        if isinstance(node, ast.keyword) and node.arg == "install_requires":
            lists["install_requires"] = [ast.literal_eval(elt) for elt in node.value.elts]
        elif isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name) \
                and node.targets[0].id.isupper() and isinstance(node.value, ast.List):
            lists[node.targets[0].id] = [ast.literal_eval(elt) for elt in node.value.elts]
    assert "install_requires" in lists, "setup.py has no install_requires"
    return lists


def _names(requirements: list[str]) -> set[str]:
    import re

    return {_canonical(re.split(r"[\s<>=!~;\[]", r)[0]) for r in requirements}


def _install_requires() -> set[str]:
    """Distribution names (canonical) a runtime import may come from: install_requires and the runtime extras
    (train, dask; ros packages are checked against package.xml)."""
    lists = _requirement_lists()
    return _names(lists["install_requires"] + lists["TRAIN"] + lists["DASK"])


def _manifest_dependencies() -> tuple[set[str], str]:
    """package.xml: the names of its exec_depend / depend elements, and the text of its comments."""
    import xml.etree.ElementTree as ET

    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.parse(REPO_ROOT / "package.xml", parser).getroot()
    depends = {(e.text or "").strip() for tag in ("exec_depend", "depend") for e in root.iter(tag)}
    comments = " ".join(e.text or "" for e in root.iter() if e.tag is ET.Comment)
    return depends, comments


@pytest.mark.slow
def test_every_third_party_import_is_a_declared_dependency() -> None:
    """What the code imports (not what package.xml already lists) decides: each Python module's distribution
    (from its installed metadata) is in install_requires and, by its rosdep key, an exec_depend of package.xml
    (or, with no rosdep key, named in a package.xml comment); each ROS package is an exec_depend."""
    imports = _third_party_imports()
    assert {"torch", "numpy", "numba", "sklearn", "rclpy", "diagnostic_msgs", "launch_ros"} <= imports
    requires = _install_requires()
    depends, comments = _manifest_dependencies()
    installed = importlib.metadata.packages_distributions()
    problems = []
    for module in sorted(imports):
        if module not in ROSDEP_KEYS:
            if module not in depends:
                problems.append(f"ROS package {module}: no <exec_depend>{module}</exec_depend> in package.xml")
            continue
        dists = installed.get(module)
        if not dists:
            problems.append(f"{module}: not installed, so its distribution is unknown")
            continue
        dist = _canonical(dists[0])
        if dist not in requires:
            problems.append(f"{module}: distribution {dists[0]} is not in setup.py install_requires")
        key = ROSDEP_KEYS[module]
        if key is not None and key not in depends:
            problems.append(f"{module}: no <exec_depend>{key}</exec_depend> in package.xml")
        if key is None and dists[0].lower() not in comments.lower():
            problems.append(f"{module}: {dists[0]} has no rosdep key and no package.xml comment names it")
    assert not problems, "\n".join(problems)


def test_node_wrapper_execs_the_console_script_beside_it(tmp_path: Path) -> None:
    """The pip-route wrapper in lib/bptsb_ros runs <prefix>/bin/<node> with all arguments, from any cwd."""
    prefix = tmp_path / "prefix with space"
    (prefix / "bin").mkdir(parents=True)
    (prefix / "lib" / PACKAGE).mkdir(parents=True)
    target = prefix / "bin" / "body_sim"
    target.write_text('#!/bin/sh\nprintf "%s|" "$0" "$@"\n')
    target.chmod(0o755)
    wrapper = prefix / "lib" / PACKAGE / "body_sim"
    wrapper.write_text(_wrapper_text("body_sim"))
    wrapper.chmod(0o755)

    out = subprocess.run([str(wrapper), "--ros-args", "-p", "x:=a b"], cwd="/", capture_output=True, text=True,
                         timeout=30)
    assert out.returncode == 0, out.stderr
    argv0, *args = out.stdout.rstrip("|").split("|")
    assert Path(argv0).resolve() == target.resolve()
    assert args == ["--ros-args", "-p", "x:=a b"]


def _bptsb_command() -> list[str]:
    script = Path(sys.executable).parent / "bptsb"
    return [str(script)] if script.exists() else [sys.executable, "-m", "bptsb_ros.cli"]


def test_bptsb_help_lists_every_subcommand() -> None:
    from bptsb_ros.cli import SUBCOMMANDS

    out = subprocess.run([*_bptsb_command(), "--help"], capture_output=True, text=True, timeout=60,
                         cwd=REPO_ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage: bptsb")
    for name in SUBCOMMANDS:
        assert f"    {name} " in out.stdout or f"    {name}\n" in out.stdout, f"{name} missing from:\n{out.stdout}"


def test_every_subcommand_explains_itself(capsys: pytest.CaptureFixture[str]) -> None:
    from bptsb_ros.cli import SUBCOMMANDS, build_parser

    parser = build_parser()
    for name in SUBCOMMANDS:
        with pytest.raises(SystemExit) as exit_info:
            parser.parse_args([name, "--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        assert text.startswith(f"usage: bptsb {name}"), text
        assert len(text.splitlines()) > 3, f"bptsb {name} --help says too little:\n{text}"


def test_cli_help_does_not_import_heavy_modules() -> None:
    code = (
        "import sys, contextlib, io\n"
        "from bptsb_ros.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        "print(sorted(m for m in ('torch', 'rclpy', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO_ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", f"bptsb --help imported {out.stdout.strip()}: import them inside run()"


def test_cli_version_is_the_manifest_version() -> None:
    import xml.etree.ElementTree as ET

    version = ET.parse(REPO_ROOT / "package.xml").getroot().findtext("version")
    out = subprocess.run([sys.executable, "-m", "bptsb_ros.cli", "--version"], capture_output=True, text=True,
                         check=True, cwd=REPO_ROOT)
    assert out.stdout.strip() == f"bptsb {version}"


def test_citation_file_cites_the_paper_and_this_version() -> None:
    import xml.etree.ElementTree as ET

    import yaml

    cff = yaml.safe_load((REPO_ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0"
    assert cff["version"] == ET.parse(REPO_ROOT / "package.xml").getroot().findtext("version")
    paper = cff["preferred-citation"]
    assert paper["title"].startswith("Backpropagation through Soft Body")
    assert [a["family-names"] for a in paper["authors"]] == ["Tomioka", "Inoue", "Kuniyoshi", "Nakajima"]
    assert (REPO_ROOT / "LICENSE").read_text().lstrip().startswith("Apache License")
    assert cff["license"] == "Apache-2.0"
    assert cff["references"][0]["title"] == paper["title"] and cff["references"][0]["type"] == "article"


def test_the_version_is_released_in_the_changelog_on_the_citations_date() -> None:
    """The version has a CHANGELOG section dated as CITATION.cff's date-released (not "unreleased")."""
    import datetime
    import re
    import xml.etree.ElementTree as ET

    import yaml

    version = ET.parse(REPO_ROOT / "package.xml").getroot().findtext("version")
    released = str(yaml.safe_load((REPO_ROOT / "CITATION.cff").read_text())["date-released"])
    datetime.date.fromisoformat(released)
    heading = re.search(rf"^## {re.escape(version)} — (.+)$", (REPO_ROOT / "CHANGELOG.md").read_text(), re.MULTILINE)
    assert heading, f"CHANGELOG.md has no section for {version}"
    assert heading.group(1).strip() == released


def test_pyproject_names_the_setuptools_backend_and_the_installed_version_matches() -> None:
    import tomllib
    import xml.etree.ElementTree as ET

    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())
    assert project["build-system"]["build-backend"] == "setuptools.build_meta"
    assert project["tool"]["ruff"]["line-length"] == 120
    try:
        installed = importlib.metadata.version(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        pytest.skip(f"{PACKAGE} is not pip-installed (make venv installs it)")
    assert installed == ET.parse(REPO_ROOT / "package.xml").getroot().findtext("version")


def test_the_light_install_leaves_torch_numba_and_sklearn_to_extras() -> None:
    """The base install is the light route (bags, replay, IPC): torch, numba and scikit-learn come with the
    ``train`` extra, Dask with ``dask``; requirements-ros.txt (docs/ros/index.md) is the base plus ``train``."""
    lists = _requirement_lists()
    base = _names(lists["install_requires"])
    assert not base & {"torch", "numba", "scikit-learn", "distributed"}, base
    assert {"torch", "numba", "scikit-learn"} <= _names(lists["TRAIN"])
    lines = [line.split("#")[0].strip() for line in (REPO_ROOT / "requirements-ros.txt").read_text().splitlines()]
    assert sorted(filter(None, lines)) == sorted(lists["install_requires"] + lists["TRAIN"])


@pytest.mark.slow
def test_the_built_wheel_carries_the_package_data_and_finds_it_anywhere(tmp_path: Path) -> None:
    """A wheel built from the checkout holds the configs, launch files, layouts, the example agent and bag, the
    experiment settings and durations; unpacked away from the checkout, bptsb_ros.files.package_data finds them
    there."""
    import zipfile

    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                          str(tmp_path / "dist"), str(REPO_ROOT)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob(f"{PACKAGE}-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {f"{PACKAGE}/share/config/{p.name}" for p in (REPO_ROOT / "config").iterdir() if p.is_file()}
    expected |= {f"{PACKAGE}/share/launch/{p.name}" for p in (REPO_ROOT / "launch").glob("*.launch.py")}
    for kind, folder in (("lissajous_agent", "bags/lissajous_agent"),
                         ("lissajous_closed_example", "bags/lissajous_closed_example")):
        expected |= {f"{PACKAGE}/share/examples/{kind}/{p.name}" for p in (REPO_ROOT / folder).iterdir()}
    expected |= {f"{PACKAGE}/experiments/durations.yaml", f"{PACKAGE}/experiments/settings/narma-ipc.yaml",
                 f"{PACKAGE}/py.typed"}
    assert expected <= names, sorted(expected - names)
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    code = ("from bptsb_ros import __version__; from bptsb_ros.files import package_data as d; "
            "from bptsb_ros.experiments.common import packaged_configs; print(__version__); print(d.config_dir()); "
            "print(d.launch_dir()); "
            "print(d.example_agent()); print(' '.join(packaged_configs()))")
    env = dict(os.environ, PYTHONPATH=str(site), AMENT_PREFIX_PATH="")
    run = subprocess.run([sys.executable, "-c", code], cwd=elsewhere, env=env, capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr
    version, config, launch, agent, names_line = run.stdout.splitlines()
    import xml.etree.ElementTree as ET

    assert version == ET.parse(REPO_ROOT / "package.xml").getroot().findtext("version")
    assert Path(config) == site / PACKAGE / "share" / "config"
    assert Path(launch) == site / PACKAGE / "share" / "launch"
    assert (Path(agent) / "checkpoint.pt").is_file()
    assert "lissajous_single" in names_line.split() and "body_sim_params" not in names_line.split()


def test_package_data_lists_what_setup_py_copies_and_finds_the_checkout() -> None:
    import ast

    from bptsb_ros.files import package_data

    tree = ast.parse((REPO_ROOT / "setup.py").read_text())
    copied = next(ast.literal_eval(node.value) for node in ast.walk(tree) if isinstance(node, ast.Assign)
                  and getattr(node.targets[0], "id", None) == "SHARED_DATA")
    assert {name: source for name, (source, _) in copied.items()} == package_data.SHARED
    assert package_data.checkout_root() == REPO_ROOT
    assert package_data.config_dir() == REPO_ROOT / "config"  # an editable install reads the checkout
    assert package_data.rviz_config().is_file() and package_data.foxglove_layout().is_file()
    with pytest.raises(ValueError, match="unknown package data"):
        package_data.data_dir("../etc")


def test_missing_package_data_is_one_line_naming_where_it_looked(monkeypatch: pytest.MonkeyPatch) -> None:
    from bptsb_ros.config import ConfigError
    from bptsb_ros.experiments.common import packaged_configs
    from bptsb_ros.files import package_data

    monkeypatch.setattr(package_data, "checkout_root", lambda: None)
    monkeypatch.setattr(package_data, "_ament_share", lambda kind: None)
    with pytest.raises(package_data.PackageDataError, match="config files are missing"):
        package_data.config_dir()
    with pytest.raises(ConfigError, match="reinstall bptsb_ros"):
        packaged_configs()
