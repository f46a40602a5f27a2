"""``feedback_brain``: the closed loop. Body state at step k → rest lengths in force at step k+1,
``FeedbackLayer.rest_length_from_features(l, s_k)`` = l·(1 + W·[s_k, 1]) with the agent's fitted feedback layer
(the function ``FeedbackLayer.rest_length`` applies offline to ``state_features`` of the body state).

The state comes from ``body/spring_lengths`` (state type ``spring_length``, the default) or
``body/mass_states`` (``position``, ``velocity``, ``acceleration`` = effort / mass, see
``messages.acceleration_from_effort``). With
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

import torch
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.live.feedback import FeedbackCommands
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.params import Param, ParameterError
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.ros.topics import feedback_state_key, spring_names

NODE = "feedback_brain"
PARAMS = (
    Param("open_loop_steps", 0, "steps 0..W driven by the agent's SWG before the feedback layer takes over "
          "(0: closed loop from rest)", "int", minimum=0),
    Param("gain", 1.0, "feedback gain g: rest lengths l·(1 + g·W·[s, 1]) (1: the fitted layer, 0: the trained rest "
          "lengths)", "float", minimum=0.0, maximum=10.0, dynamic=True),
    Param("noise", 0.0, "σ of Gaussian noise added to every state feature before the feedback layer, in the "
          "state's unit (m, m/s or m/s²); 0: none", "float", minimum=0.0, dynamic=True),
    Param("noise_seed", 0, "seed of the feedback noise", "int", minimum=0),
) + topic_params(("clock", "spring_lengths", "mass_states", "rest_length_cmd"))


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
        self.pub = self.output(JointState, p["topics.rest_length_cmd"], m.command_qos(self.depth))
        self.command = self.joint_state_out(self.names, "position")
        self.subscribe_newest(Clock, p["topics.clock"], self._on_clock, m.state_qos(self.depth))
        state_topic = p[f"topics.{feedback_state_key(self.state_type)}"]
        self.subscribe_newest(JointState, state_topic, self._on_state, m.state_qos(self.depth))
        self.get_logger().info(f"feedback layer of {self.source_text()}: state {self.state_type} from {state_topic}, "
                               f"{len(self.names)} springs, open loop for steps 0..{self.open_loop}, gain "
                               f"{p['gain']:g}, noise σ {p['noise']:g}")

    def _send(self, step: int, rest: torch.Tensor, started: float) -> None:
        self.publish_timed(self.pub, self.command(step, rest.reshape(-1).double().numpy()), started)

    def _on_clock(self, msg: Clock) -> None:
        started = time.monotonic()
        step = m.step_of(msg.clock, self.dt_ns)
        rest = self.commands.on_clock(step)
        if rest is not None:
            self._send(step, rest, started)

    def _on_state(self, msg: JointState) -> None:
        started = time.monotonic()
        step = m.step_of(msg.header.stamp, self.dt_ns)
        field = {"spring_length": msg.position, "position": msg.position, "velocity": msg.velocity,
                 "acceleration": msg.effort}[self.state_type]
        rest = self.commands.on_state(step, m.as_array(field), self.p["gain"], self.p["noise"])
        if isinstance(rest, str):
            self.warn(f"bad_state:{self.state_type}", rest)
        elif rest is not None:
            self._send(step + 1, rest, started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, FeedbackBrain, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
