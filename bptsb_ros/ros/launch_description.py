"""The loops as ``ros2 launch`` descriptions (``launch/<loop>.launch.py`` call :func:`ros_launch_description`): the
nodes (a process each, or body and brains in one with ``composed:=true``), their parameters (written from the launch
arguments by :mod:`bptsb_ros.live.loops`), the recorder with ``bag:=DIR``, and what the launch does when a node
exits (:func:`node_exit_verdict`). The loops themselves, their arguments and their checks are ROS-free, in
:mod:`bptsb_ros.live.loops`.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from bptsb_ros.interface.topics import TOPICS
from bptsb_ros.live.loops import (
    LOOPS,
    LaunchArgumentError,
    NamespaceError,
    body_process_nodes,
    launch_arguments,
    loop_node_parameters,
    loop_topic,
    namespace_remaps,
    normalize_namespace,
    params_file_text,
    resolve_arguments,
)

#: the executable of ``composed:=true`` and ``recorder_in_body:=true`` (body_sim with the brains and/or the recorder in
#: one process; its exit code is the body's, else the hosted recorder's)
COMPOSED = "bptsb_composed"


def node_exit_verdict(executable: str, returncode: int, shutting_down: bool, body_finished: bool = False) -> str:
    """What the launch does when a node of the loop exits: ``finished`` (body_sim's clean end of the run, alone
    or composed with the brains: shut the launch down, exit 0), ``stopped`` (a clean exit while the launch shuts
    down or after body_sim finished), ``interrupted`` (another clean exit: the node was stopped from outside the
    launch, e.g. SIGINT sent to the nodes and not to ``ros2 launch``; the launch shuts down, logs it as info and
    exits 0 — the body's summary still decides whether the run counts) or a failure message (the launch shuts
    down and exits non-zero)."""
    if returncode == 0 and executable in ("body_sim", COMPOSED):
        return "finished"
    if returncode == 0 and (shutting_down or body_finished):
        return "stopped"
    if returncode == 0:
        return "interrupted"
    if shutting_down:
        return f"{executable} exited with code {returncode} while the loop was stopping"
    return (f"{executable} exited with code {returncode} before the end of the run; the loop is broken, "
            "shutting every node down")


#: Seconds a node of a launched loop may take to stop after SIGINT before launch escalates to SIGTERM (launch's
#: default is 5 s): the recorder may drain for up to its stop_timeout (8 s), the body waits up to final_ack_timeout
#: (5 s) for the recorder's acknowledgements.
STOP_GRACE_S = 12


class LoopNodeFailed(RuntimeError):
    """A node of a launched loop failed or ended early: raised inside the launch so that it exits non-zero."""


def ros_launch_description(loop_name: str):  # -> launch.LaunchDescription
    """``LaunchDescription`` of a loop for ``ros2 launch bptsb_ros <loop>.launch.py`` (needs launch, launch_ros).

    The nodes are declared statically (``ros2 launch -p`` and launch introspection list them); their parameters
    are params files written at launch time from the arguments (:func:`loop_node_parameters`: the same
    processes and parameters as ``bptsb launch``), and the recorder runs only with ``bag:=DIR``. ``body_sim`` and
    the brains run as a process each, or with ``composed:=true`` as one ``bptsb_composed`` process that builds
    them all (``--nodes``; a params file with a section per node; its exit code is the body's, else the hosted
    recorder's); ``recorder_in_body:=true`` builds the recorder in that process too (with the body alone when not
    composed). Every shape is declared, each node under the condition of its own process. The arguments are
    checked first (:func:`resolve_arguments`; closed loops require ``agent``): a bad one stops the launch before
    any node starts, with the reason and a non-zero exit. When ``body_sim`` ends the run the launch shuts down and
    exits 0; when any node exits otherwise (a brain that cannot start, a crash, a failed stop) the whole loop is
    shut down and the launch exits non-zero (:func:`node_exit_verdict`).
    """

    import json
    import shutil

    from launch.actions import (
        DeclareLaunchArgument,
        EmitEvent,
        ExecuteProcess,
        LogInfo,
        OpaqueFunction,
        RegisterEventHandler,
    )
    from launch.condition import Condition
    from launch.conditions import UnlessCondition
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown
    from launch.substitution import Substitution
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node
    from launch_ros.utilities import make_namespace_absolute, prefix_namespace

    from bptsb_ros.live.summary import brain_problem
    from launch import LaunchDescription

    loop = LOOPS[loop_name]
    arguments = launch_arguments(loop)
    state: dict[str, object] = {"summary": "", "body_finished": False}

    def namespace_of(context) -> str:
        """The loops' namespace as launch_ros gives it to the nodes: ``namespace:=`` inside any PushRosNamespace."""
        pushed = context.launch_configurations.get("ros_namespace")
        try:
            return normalize_namespace(make_namespace_absolute(prefix_namespace(
                pushed, LaunchConfiguration("namespace").perform(context))) or "")
        except NamespaceError:
            return LaunchConfiguration("namespace").perform(context)  # resolve_arguments names it

    def values_of(context) -> dict[str, str]:
        values = {name: LaunchConfiguration(name).perform(context) for name in arguments}
        return {**values, "namespace": namespace_of(context)}

    class NodeParamsFile(Substitution):
        """Path of a params file with the parameters of one node, or of the ``nodes`` one process runs (a section
        each), written when the launch performs it."""

        def __init__(self, executable: str, composed: bool = False) -> None:
            super().__init__()
            self.executable, self.composed = executable, composed

        def describe(self) -> str:
            return f"<params of {self.executable} in {loop_name}, from the launch arguments>"

        def perform(self, context) -> str:
            if self.composed:  # the composed process: one section per node it builds
                from bptsb_ros.ros.composed import params_file_text as sections_text

                text = sections_text({name: node_params(name, context) for name in composed_nodes(context)}, {})
            else:
                text = params_file_text(self.executable, node_params(self.executable, context))
            handle, path = tempfile.mkstemp(prefix=f"bptsb_{loop_name}_{self.executable}_", suffix=".yaml")
            with open(handle, "w") as out:
                out.write(text)
            return path

    def node_params(executable: str, context) -> dict:
        """One node's parameters from the launch arguments; body_sim's summary path is kept in ``state`` (on_exit
        reads the summary to tell whether the brain was there)."""
        params = loop_node_parameters(loop_name, executable, values_of(context))
        if executable == "body_sim":
            if not params.get("summary_path"):
                params["summary_path"] = str(Path(tempfile.mkdtemp(prefix=f"bptsb_{loop_name}_")) /
                                             "body_summary.json")
            state["summary"] = params["summary_path"]
        return params

    def check(context, *args, **kwargs):
        del args, kwargs
        try:
            resolve_arguments(loop, values_of(context))
        except LaunchArgumentError as err:
            raise LaunchArgumentError(f"{loop_name}.launch.py: {err}") from None

    class UserParamsFile(Substitution):
        """``params_file:=`` for one node, or (none given) a second copy of the node's own parameters."""

        def __init__(self, own: NodeParamsFile) -> None:
            super().__init__()
            self.own = own

        def describe(self) -> str:
            return "<params_file:= of the launch, if any>"

        def perform(self, context) -> str:
            return LaunchConfiguration("params_file").perform(context) or self.own.perform(context)

    def flag(name: str, context) -> bool:
        return LaunchConfiguration(name).perform(context).lower() == "true"

    def recorder_in_body(context) -> bool:
        return bool(LaunchConfiguration("bag").perform(context)) and flag("recorder_in_body", context)

    def composed_nodes(context) -> list[str]:
        """The nodes the ``bptsb_composed`` process builds (:func:`body_process_nodes` of the launch arguments)."""
        return body_process_nodes(loop, composed=flag("composed", context), recorder_in_body=recorder_in_body(context))

    class ComposedNodes(Substitution):
        """``--nodes`` of the composed process (:func:`composed_nodes`)."""

        def describe(self) -> str:
            return "<body_sim[,brains][,recorder] from composed:= and recorder_in_body:=>"

        def perform(self, context) -> str:
            return ",".join(composed_nodes(context))

    class Remapped(Substitution):
        """The target of ``/clock`` or ``/diagnostics`` (``key``) in the loop's namespace."""

        def __init__(self, key: str) -> None:
            super().__init__()
            self.key = key

        def describe(self) -> str:
            return f"<{TOPICS[self.key].name} in the loop's namespace>"

        def perform(self, context) -> str:
            return loop_topic(self.key, namespace_of(context))

    def body_problem() -> str:
        try:
            summary = json.loads(Path(str(state["summary"])).read_text())
        except (OSError, ValueError):
            return ""
        return brain_problem(summary) if isinstance(summary, dict) else ""

    def on_exit(executable: str):
        def handler(event, context):
            verdict = node_exit_verdict(executable, event.returncode, context.is_shutdown,
                                        bool(state["body_finished"]))
            if verdict == "finished":
                state["body_finished"] = True
                problem = body_problem()
                if problem:
                    raise LoopNodeFailed(problem)
                return [EmitEvent(event=Shutdown(reason="body_sim finished the run"))]
            if verdict == "interrupted":
                return [LogInfo(msg=f"{executable} stopped cleanly (interrupted from outside the launch); stopping "
                                "the loop"), EmitEvent(event=Shutdown(reason=f"{executable} was interrupted"))]
            if verdict != "stopped":
                raise LoopNodeFailed(verdict)
            return None
        return handler

    def rviz(context, *args, **kwargs):
        del args, kwargs
        if LaunchConfiguration("rviz").perform(context).lower() != "true":
            return None
        if shutil.which("rviz2") is None:
            return [LogInfo(msg="rviz:=true: rviz2 is not installed here; the loop runs without it")]
        namespace = namespace_of(context)
        remaps = [arg for src, dst in namespace_remaps(namespace) for arg in ("-r", f"{src}:={dst}")]
        from bptsb_ros.live.viewers import rviz_config_text

        handle, config = tempfile.mkstemp(prefix=f"bptsb_{loop_name}_", suffix=".rviz")
        with open(handle, "w") as out:  # the package's config with the fixed frame of the loop's namespace
            out.write(rviz_config_text(rviz_config().read_text(), namespace))
        return [ExecuteProcess(cmd=["rviz2", "-d", config, "--ros-args", "-r",
                                    f"__ns:={namespace or '/'}", *remaps], name="rviz2", output="screen")]

    # the nodes of both shapes, each under the condition of its own process
    recording = Condition(predicate=lambda context: bool(LaunchConfiguration("bag").perform(context))
                          and not recorder_in_body(context))
    split = UnlessCondition(LaunchConfiguration("composed"))
    body_apart = Condition(predicate=lambda context: not flag("composed", context) and not recorder_in_body(context))
    hosting = Condition(predicate=lambda context: flag("composed", context) or recorder_in_body(context))
    executables = ["body_sim", *(b.executable for b in loop.brains), "recorder", COMPOSED]
    conditions = {"body_sim": body_apart, "recorder": recording, COMPOSED: hosting}

    def own_params(name: str) -> NodeParamsFile:
        return NodeParamsFile(name, composed=name == COMPOSED)

    remappings = [(TOPICS[k].name, Remapped(k)) for k in TOPICS if TOPICS[k].name.startswith("/")]
    # the composed process is not named (a name would rename every node in it); --nodes says which it builds
    nodes = [Node(package="bptsb_ros", executable=name, output="screen",
                  **({"arguments": ["--nodes", ComposedNodes()]} if name == COMPOSED else {"name": name}),
                  namespace=LaunchConfiguration("namespace"), remappings=remappings,
                  parameters=[own_params(name), UserParamsFile(own_params(name))],
                  ros_arguments=["--log-level", LaunchConfiguration("log_level")],
                  condition=conditions.get(name, split),
                  sigterm_timeout=str(STOP_GRACE_S))
             for name in executables]
    return LaunchDescription([
        *(DeclareLaunchArgument(name, description=text, **({} if default is None else {"default_value": default}))
          for name, (default, text) in arguments.items()),
        OpaqueFunction(function=check),
        *nodes,
        *(RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit(name)))
          for node, name in zip(nodes, executables, strict=True)),
        OpaqueFunction(function=rviz),
    ])


def rviz_config() -> Path:
    """The RViz config of the package (``config/bptsb.rviz``; :func:`bptsb_ros.files.package_data.rviz_config`)."""
    from bptsb_ros.files.package_data import rviz_config as packaged

    return packaged()
