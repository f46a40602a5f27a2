"""``feedback_brain``: the closed loop. Body state at step k → rest lengths in force at step k+1,
``FeedbackLayer.rest_length(l, s_k)`` = l·(1 + W·[s_k, 1]) with the agent's fitted feedback layer.

The state comes from ``body/spring_lengths`` (state type ``spring_length``, the default) or
``body/mass_states`` (``position``, ``velocity``, ``acceleration`` = effort / mass). With
``open_loop_steps`` = W > 0 the SWG drives steps 0…W (answering ``/clock``) and the feedback layer
takes over from step W+1 — the paper's transfer from the SWG to the feedback layer, offline
``simulate_open_loop(agent, W)`` followed by ``simulate_closed_loop(..., state=final)``. With W = 0
the loop starts from rest: the command for step 0 is the trained rest length.
"""

from __future__ import annotations

import sys
import time

import torch
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from bptsb_ros.body.msdn import BodyState
from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import BrainNode, topic_params
from bptsb_ros.ros.params import Param, ParameterError
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.ros.topics import spring_names
from bptsb_ros.sim.rollout import swg_rest_lengths

NODE = "feedback_brain"
PARAMS = (
    Param("open_loop_steps", 0, "steps 0..W driven by the agent's SWG before the feedback layer takes over "
          "(0: closed loop from rest)", "int", minimum=0),
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
        body = agent.body
        self.base = body.l.detach()
        self.names = spring_names(body.topology.n_springs)
        self.state_type = agent.feedback.state_type
        self.mass = body.mass.detach()
        self.pub = self.output(JointState, p["topics.rest_length_cmd"], m.command_qos(self.depth))
        self.create_subscription(Clock, p["topics.clock"], self._on_clock, m.state_qos(self.depth))
        state_topic = p["topics.spring_lengths"] if self.state_type == "spring_length" else p["topics.mass_states"]
        self.create_subscription(JointState, state_topic, self._on_state, m.state_qos(self.depth))
        self.get_logger().info(f"feedback layer of {self.source_text()}: state {self.state_type} from {state_topic}, "
                               f"{len(self.names)} springs, open loop for steps 0..{self.open_loop}")

    def _send(self, step: int, rest: torch.Tensor, started: float) -> None:
        msg = m.joint_state(step, self.dt_ns, self.names, position=rest.reshape(-1).double().numpy())
        self.publish_timed(self.pub, msg, started)

    def _on_clock(self, msg: Clock) -> None:
        started = time.monotonic()
        step = m.step_of(msg.clock, self.dt_ns)
        if step > self.open_loop:
            return  # answered by _on_state
        if self.open_loop == 0:
            self._send(step, self.base, started)
            return
        with torch.no_grad():
            rest = swg_rest_lengths(self.agent.body, self.agent.brain, step, 1)[0]
        self._send(step, rest, started)

    def _on_state(self, msg: JointState) -> None:
        started = time.monotonic()
        step = m.step_of(msg.header.stamp, self.dt_ns)
        if step < self.open_loop:
            return
        state = self._state(msg, step)
        if state is None:
            return
        with torch.no_grad():
            rest = self.agent.feedback.rest_length(self.base, state)
        self._send(step + 1, rest, started)

    def _state(self, msg: JointState, step: int) -> BodyState | None:
        """The fields of a BodyState the feedback layer reads (others are empty), or None if malformed."""
        dtype = self.base.dtype
        empty = torch.empty(0, dtype=dtype)
        body = self.agent.body
        if self.state_type == "spring_length":
            length = torch.from_numpy(m.as_array(msg.position)).to(dtype)
            if length.numel() != body.topology.n_springs:
                self.get_logger().warning(f"ignored spring lengths of step {step}: {length.numel()} values")
                return None
            return BodyState(empty, empty, empty, length.unsqueeze(0), step)
        field = {"position": msg.position, "velocity": msg.velocity, "acceleration": msg.effort}[self.state_type]
        x = torch.from_numpy(m.as_array(field)).to(dtype)
        if x.numel() != 2 * body.n_movable:
            self.get_logger().warning(f"ignored mass states of step {step}: {x.numel()} {self.state_type} values")
            return None
        x = x.view(1, -1, 2)
        if self.state_type == "acceleration":
            return BodyState(empty, empty, x / self.mass.unsqueeze(-1), empty, step)
        return BodyState(x, empty, empty, empty, step) if self.state_type == "position" else \
            BodyState(empty, x, empty, empty, step)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, FeedbackBrain, args)


if __name__ == "__main__":
    sys.exit(main())
