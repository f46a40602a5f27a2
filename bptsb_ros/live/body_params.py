"""Parameters of the live body (``body_sim``), ROS-free: their specs (:data:`PARAMS`, declared by the node and
read by :class:`~bptsb_ros.live.body_core.BodyCore`) and the checks that turn some of them into steps.

The specs are plain :class:`~bptsb_ros.interface.params.Param` records (no rclpy); ``docs/ros`` and the node's
``--help`` list them.
"""

from __future__ import annotations

import math

from bptsb_ros.interface.params import CPUS, EXECUTOR, LOG_LEVEL, RAW_OUTPUTS, Param, ParameterError
from bptsb_ros.interface.source import SOURCE_PARAMS
from bptsb_ros.interface.topics import (
    BODY_INPUTS,
    BODY_OUTPUTS,
    COMMAND_SOURCES,
    DEFAULT_QOS_DEPTH,
    RECORDER_ACK,
    TOPICS,
)
from bptsb_ros.live.channels import MODES
from bptsb_ros.live.safety import (
    DEFAULT_CONTROL_CALLERS,
    DEFAULT_MAX_FORCE,
    DEFAULT_MAX_WIND,
    DEFAULT_PERTURB_PUBLISHERS,
    DIVERGENCE_POLICIES,
)

NODE = "body_sim"
#: furthest ahead [steps] a perturbation may be stamped, and the most that may wait at once
MAX_PERTURB_AHEAD = 10**9
MAX_PENDING_PERTURBATIONS = 1000
#: perturbed steps listed in the run summary (all are counted)
LISTED_PERTURBATIONS = 20
#: what the ROS graph reports as the node name of an endpoint whose node it has not discovered yet
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
PUBLISHED = BODY_OUTPUTS
#: body outputs that say again what body/positions and the commands say: every ``state_every`` steps
SLOW_OUTPUTS: tuple[str, ...] = ("mass_states", "spring_lengths", "rest_length", "external_force")
SUBSCRIBED = BODY_INPUTS

PARAMS: tuple[Param, ...] = SOURCE_PARAMS + (
    Param("mode", "lockstep", "timing mode: lockstep (deterministic, waits for commands) or realtime "
          "(wall-clock timer at rate_scale/dt)", "str", choices=MODES),
    Param("rate_scale", 1.0, "realtime: sim seconds per wall second (1 = real time); lockstep: pace of steps "
          "integrated with the safe command while a brain is silent", "float", positive=True, dynamic=True),
    Param("duration", 0.0, "sim time to run [s]; the node exits after the last step (0: run until stopped)",
          "float", minimum=0.0),
    Param("wall_duration", 0.0, "realtime: wall seconds to run from the first step, then exit (0: no limit)",
          "float", minimum=0.0),
    Param("max_steps", 0, "steps to run, overrides duration when > 0 (0: use duration)", "int", minimum=0),
    Param("wait_for", [], "command sources whose command for step k must arrive before step k is integrated "
          "in lockstep (realtime: sources watched for silence)", "str_list", choices=tuple(COMMAND_SOURCES)),
    Param("wait_for_subscribers", [], "startup: 'topic:count' entries; the first step waits until each topic "
          "has that many subscribers (e.g. the brains and the recorder)", "str_list"),
    Param("startup_timeout", 30.0, "startup: wall seconds to wait for brains and subscribers before starting "
          "anyway (silent sources get the safe command)", "float", positive=True),
    Param("command_timeout", 2.0, "wall seconds without the awaited command before a source counts as silent "
          "and the safe command is used", "float", positive=True),
    Param("max_command_age", 0.1, "realtime: oldest usable command [sim s]; older ones are stale", "float",
          positive=True),
    Param("wait_for_recorder", False, "lockstep: before announcing step k, wait until the recorder acknowledged on "
          "topics.recorder_ack that it has recorded step k - recorder_window (a lockstep recording then loses "
          "nothing)", "bool"),
    Param("recorder_window", 0, "lockstep with wait_for_recorder: steps the body may run ahead of the recorder's "
          "acknowledgement, below qos_depth; 0: qos_depth / 2", "int", minimum=0),
    Param("recorder_timeout", 30.0, "lockstep with wait_for_recorder: wall seconds without progress of the recorder's "
          "acknowledgement before the body goes on without waiting (logged; the recording counts what it loses)",
          "float", positive=True),
    Param("recorder_publishers", ["recorder"], "node names allowed to acknowledge on topics.recorder_ack; an "
          "acknowledgement is ignored while another node publishes there", "str_list"),
    Param("final_ack_timeout", 5.0, "at exit, wall seconds to wait until reliable subscribers (the recorder) "
          "acknowledged every message", "float", minimum=0.0),
    RAW_OUTPUTS,
    Param("marker_every", 5, "publish body/markers every this many steps", "int", minimum=1, dynamic=True),
    Param("state_every", 10, "publish body/mass_states, body/spring_lengths, body/rest_length and "
          "body/external_force every this many steps, at steps 2, 4, 6 and 8 modulo it (1: every step); /clock and "
          "body/positions, the state of every step, go out every step", "int", minimum=1, dynamic=True),
    Param("every_step", [], "of those four topics, the ones published every step anyway (a node that reads them, "
          "e.g. a feedback brain on mass states: the launchers add what the loop's brains read)", "str_list",
          choices=SLOW_OUTPUTS),
    Param("frame_id", "msdn", "frame of positions and markers (the body plane, metres, y up)", "str"),
    Param("diagnostics_period", 1.0, "wall seconds between /diagnostics messages", "float", positive=True,
          dynamic=True),
    Param("wind", [0.0, 0.0], "constant wind force (x, y) [N] on every movable mass from the next step on, within "
          "max_wind; a message on env/wind replaces it (realtime, or lockstep runs that are not compared offline)",
          "float_list", size=2, dynamic=True),
    EXECUTOR,
    LOG_LEVEL,
    Param("summary_path", "", "write the run summary (timing, rejections) as JSON here at exit (empty: don't)",
          "str"),
    Param("timing_path", "", "realtime: write every step's wall times (due, began, integrated, done; "
          "bptsb_ros.live.step_times) here as .npz at exit, 40 bytes a step kept in memory (empty: don't)", "str"),
    Param("rt_priority", 0, "realtime: run the stepping thread under SCHED_FIFO at this priority (1-99; needs "
          "CAP_SYS_NICE or root, else a warning and the normal scheduler), so that other processes cannot preempt "
          "a step; 0: the normal scheduler", "int", minimum=0, maximum=99),
    CPUS,
    Param("busy_wait", 0.002, "realtime under rt_priority: the last this many wall seconds before each step is due "
          "(at most half a period) are spent polling for messages instead of sleeping, so that the step starts on a "
          "core that is not asleep and that nothing else ran on just before; 0: sleep until the step is due",
          "float", minimum=0.0),
    Param("qos_depth", DEFAULT_QOS_DEPTH, "history depth of every topic (reliable)", "int", minimum=1),
    Param("max_rest_length", 0.0, "largest accepted rest-length command [m]; 0: 10 x "
          "the diagonal of the body's bounding box", "float", minimum=0.0),
    Param("min_rest_length", 0.0, "rest-length commands must be > this [m]; 0: 0, unless the agent's SWG itself "
          "commands rest lengths <= 0 (amplitude > 1): then its lowest SWG rest length minus one full swing",
          "float"),
    Param("max_force", DEFAULT_MAX_FORCE, "largest accepted |component| of a force command [N]", "float",
          positive=True),
    Param("max_wind", DEFAULT_MAX_WIND, "largest accepted |component| of a wind message [N]", "float",
          positive=True),
    Param("command_publishers", [], "node names ('name' or '/namespace/name') allowed to publish commands; a "
          "command is rejected while any other node publishes on its topic; empty: this package's brains "
          "(swg_brain, feedback_brain: rest lengths; mlp_brain: forces; wind_source: wind; mnist_brain: resets); "
          "'*': any node", "str_list"),
    Param("perturb_at", -1.0, "sim time [s] at which the movable masses are displaced by N(0, perturb_sigma²) per "
          "coordinate (the paper's perturbation; the state of that step is displaced, velocities kept); negative: "
          "none", "float"),
    Param("perturb_sigma", 0.0, "standard deviation of the scheduled perturbation [m]", "float", minimum=0.0),
    Param("perturb_seed", 0, "seed of the scheduled perturbation's standard-normal pattern "
          "(bptsb_ros.sim.perturbation)", "int"),
    Param("perturb_publishers", list(DEFAULT_PERTURB_PUBLISHERS), "node names allowed to publish on body/perturb "
          "('*': any node)", "str_list"),
    Param("reset_every", 0, "resets (body/reset, loop mnist_drawing): the body takes a reset only at steps k with "
          "k % reset_every == 0 (with 'reset' in wait_for it waits for one there, lockstep only); the state of step k "
          "is then the body at rest at layout + displacement; 0: no resets", "int", minimum=0),
    Param("start_paused", False, "start paused: the first step waits for the ~/resume or ~/step service (whether "
          "the body is paused now is on /diagnostics, not in this parameter)", "bool"),
    Param("control_callers", list(DEFAULT_CONTROL_CALLERS), "node names ('name' or '/namespace/name') allowed to call "
          "~/pause, ~/resume, ~/step and ~/reset; a call is refused while any other node has a client of that "
          "service; default: the ros2 command line (ros2 service call); '*': any node", "str_list"),
    Param("pause_timeout", 600.0, "wall seconds a paused body waits for ~/resume or ~/step before it ends the run "
          "(exit status 1, named in the log and the run summary), so a forgotten pause cannot hold a launch forever; "
          "0: no limit", "float", minimum=0.0),
    Param("pause_notice_period", 30.0, "while paused, a log line every this many wall seconds says so (and how long "
          "until pause_timeout)", "float", positive=True, dynamic=True),
    Param("step_count", 1, "steps one call of the ~/step service advances a paused body", "int", minimum=1,
          dynamic=True),
    Param("on_divergence", "restore", "when a step diverges: restore (last good state + safe command, go on) or "
          "stop (end the run cleanly); an ERROR diagnostic is published either way", "str",
          choices=DIVERGENCE_POLICIES),
) + tuple(Param(f"topics.{key}", TOPICS[key].name, f"topic name of {TOPICS[key].type}", "str")
          for key in PUBLISHED + SUBSCRIBED + (RECORDER_ACK,))


def perturb_step(at: float, dt: float, max_steps: int) -> int:
    """The step of a perturbation scheduled at sim time ``at`` >= 0 [s]: round(at / dt), at most ``max_steps``
    (the run's last step; 0: no end, then at most MAX_PERTURB_AHEAD). Raises ParameterError naming the limit
    (checked in floats first: ``at`` = 1e307 would overflow the integer conversion)."""
    limit = max_steps or MAX_PERTURB_AHEAD
    steps = at / dt
    if not math.isfinite(steps) or steps >= limit + 0.5:
        end = (f"after the run's last step ({max_steps * dt:g} s)" if max_steps else
               f"more than {MAX_PERTURB_AHEAD:g} steps ({MAX_PERTURB_AHEAD * dt:g} s) ahead")
        raise ParameterError(f"parameter 'perturb_at': {at:g} s is {end}")
    return int(round(steps))


def parse_wait_for_subscribers(entries: list[str]) -> list[tuple[str, int]]:
    """``['topic:count', ...]`` → [(topic, count)]; raises ParameterError naming the bad entry."""
    out = []
    for entry in entries:
        topic, sep, count = entry.rpartition(":")
        if not sep or not topic or not count.isdigit() or int(count) < 1:
            raise ParameterError(f"parameter 'wait_for_subscribers': entry {entry!r} must look like 'topic:count' "
                                 "with count >= 1")
        out.append((topic, int(count)))
    return out
