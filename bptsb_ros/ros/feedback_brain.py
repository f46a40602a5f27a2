"""``feedback_brain``: the closed loop. Body state at step k → rest lengths in force at step k+1,
``FeedbackLayer.rest_length_from_features(l, s_k)`` = l·(1 + W·[s_k, 1]) with the agent's fitted feedback layer
(the function ``FeedbackLayer.rest_length`` applies offline to ``state_features`` of the body state).

The state comes from ``body/positions`` (state type ``spring_length``, the default: the spring lengths computed from
the mass positions as the body computes them, ``live.feedback_loop.spring_lengths``) or ``body/mass_states``
(``position``, ``velocity``, ``acceleration`` = effort / mass, see ``messages.acceleration_from_effort``; the
launchers have the body publish it every step). With
``open_loop_steps`` = W > 0 the SWG drives steps 0…W (answering ``/clock``) and the feedback layer
takes over from step W+1 — the paper's transfer from the SWG to the feedback layer, offline
``simulate_open_loop(agent, W)`` followed by ``simulate_closed_loop(..., state=final)``. With W = 0
the loop starts from rest: the command for step 0 is the trained rest length.

Two live parameters perturb the loop (``ros2 param set /feedback_brain gain 0.5``): ``gain`` g scales the
feedback, l·(1 + g·W·[s_k, 1]) (1: as fitted), and ``noise`` σ adds Gaussian noise N(0, σ²) to every state
feature before the layer (seeded by ``noise_seed``). At their defaults the commands equal the offline loop's.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from geometry_msgs.msg import PoseArray
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.interface.params import Param, ParameterError
from bptsb_ros.interface.topics import feedback_state_key, mass_dof_names, spring_names, stamp_to_step
from bptsb_ros.live.feedback_loop import FeedbackCommands
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.cdr_in import JointStateReader, PoseArrayReader
from bptsb_ros.ros.runtime import StopFlag, run_node

NODE = "feedback_brain"
PARAMS = (
    Param("open_loop_steps", 0, "steps 0..W driven by the agent's SWG before the feedback layer takes over "
          "(0: closed loop from rest)", "int", minimum=0),
    Param("gain", 1.0, "feedback gain g: rest lengths l·(1 + g·W·[s, 1]) (1: the fitted layer, 0: the trained rest "
          "lengths)", "float", minimum=0.0, maximum=10.0, dynamic=True),
    Param("noise", 0.0, "σ of Gaussian noise added to every state feature before the feedback layer, in the "
          "state's unit (m, m/s or m/s²); 0: none", "float", minimum=0.0, dynamic=True),
    Param("noise_seed", 0, "seed of the feedback noise", "int", minimum=0),
) + topic_params(("clock", "positions", "mass_states", "rest_length_cmd"))


class FeedbackBrain(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        agent, p = self.agent, self.p
        if agent.feedback is None:
            raise ParameterError(f"parameter 'agent': {self.source_text()} has no feedback layer")
        if not self.trained:
            raise ParameterError("parameter 'agent': feedback_brain needs a trained agent with a fitted feedback "
                                 "layer (bptsb train fits it); got none")
        from bptsb_ros.training.checkpoint import feedback_fitted

        if not feedback_fitted(p["agent"]):
            raise ParameterError(f"parameter 'agent': the feedback layer of {p['agent']} was never fitted")
        self.open_loop = int(p["open_loop_steps"])
        if self.open_loop and not isinstance(agent.brain, SineWaveGenerator):
            raise ParameterError("parameter 'open_loop_steps': > 0 needs an SWG agent")
        self.commands = FeedbackCommands(agent, self.open_loop, p["noise_seed"])
        self.names = spring_names(agent.body.topology.n_springs)
        self.state_type = agent.feedback.state_type
        self.command = self.joint_state_out(self.names, "position")
        self.clock_sub = self.subscribe_newest(Clock, p["topics.clock"], self._on_clock, m.state_qos(self.depth),
                                               raw=True)
        self.feed_sim_time()  # from the ticks, then (past the open loop) from the states' stamps
        key = feedback_state_key(self.state_type)
        state_topic = p[f"topics.{key}"]
        if key == "positions":
            self.reader: PoseArrayReader | JointStateReader = PoseArrayReader()
            self.subscribe_newest(PoseArray, state_topic, self._on_state, m.state_qos(self.depth), raw=True)
        else:
            self.reader = JointStateReader(mass_dof_names(agent.body.movable_index.tolist()))
            self.subscribe_newest(JointState, state_topic, self._on_state, m.state_qos(self.depth), raw=True)
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.pub = self.output(JointState, p["topics.rest_length_cmd"], m.command_qos(self.depth))
        self.get_logger().info(f"feedback layer of {self.source_text()}: state {self.state_type} from {state_topic}, "
                               f"{len(self.names)} springs, open loop for steps 0..{self.open_loop}, gain "
                               f"{p['gain']:g}, noise σ {p['noise']:g}")

    def _send(self, step: int, rest: np.ndarray, started: float) -> None:
        self.publish_timed(self.pub, self.command(step, rest.reshape(-1)), started)

    def _on_clock(self, data: bytes) -> None:
        started = time.monotonic()
        step = self.clock_step(data)
        rest = self.commands.on_clock(step)
        if rest is not None:
            self._send(step, rest, started)
        elif self.clock_sub is not None:  # past the open loop (sim time never goes back): the ticks are not needed
            self.destroy_trigger(self.clock_sub)
            self.clock_sub = None

    def _state_values(self, data: bytes) -> tuple[int, np.ndarray]:
        """The step and the values of a state message: positions (N, 2) of ``body/positions``, or the field of
        ``body/mass_states`` that the state type reads (from its bytes, or deserialized when they are unusual)."""
        read = self.reader.read(data)
        if isinstance(self.reader, PoseArrayReader):
            if read is not None:
                ns, values = read
            else:
                msg = deserialize_message(data, PoseArray)
                ns, values = m.stamp_ns(msg.header.stamp), m.pose_array_positions(msg)
        else:
            field = {"position": "position", "velocity": "velocity", "acceleration": "effort"}[self.state_type]
            if read is not None:
                ns, values = read.stamp_ns, getattr(read, field)
            else:
                msg = deserialize_message(data, JointState)
                ns, values = m.stamp_ns(msg.header.stamp), m.as_array(getattr(msg, field))
        if self.clock_sub is None:
            self.sim_time(ns)
        return stamp_to_step(0, ns, self.dt_ns), values

    def _on_state(self, data: bytes) -> None:
        started = time.monotonic()
        step, values = self._state_values(data)
        rest = self.commands.on_state(step, values, self.p["gain"], self.p["noise"])
        if isinstance(rest, str):
            self.warn(f"bad_state:{self.state_type}", rest)
        elif rest is not None:
            self._send(step + 1, rest, started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, FeedbackBrain, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
