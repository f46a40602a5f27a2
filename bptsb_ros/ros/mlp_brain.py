"""``mlp_brain``: task input → forces on the movable masses, by the agent's MLP or linear input layer.

Each ``task/input`` message u stamped t_k becomes the force command in force at step k,
``bptsb_ros.agent.brain_forces(agent, input_scale·u)`` — the function the offline simulation and
NARMA training use (the CMP gets no force), evaluated in numpy from the trained weights
(:class:`~bptsb_ros.live.inference.ForceMap`). Published as ``brain/force`` (JointState effort, newtons).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from bptsb_ros.brains import LinearInputLayer, MLPBrain
from bptsb_ros.interface.params import Param, ParameterError
from bptsb_ros.interface.topics import input_names, mass_dof_names, stamp_to_step
from bptsb_ros.live.inference import ForceMap
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.cdr_in import JointStateReader
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.sim.inputs import brain_input

NODE = "mlp_brain"
PARAMS = (
    Param("input_scale", 0.0, "brain input = input_scale × u; 0: the agent config's narma.input_scale", "float",
          minimum=0.0),
) + topic_params(("task_input", "force_cmd"))


class MlpBrain(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        agent = self.agent
        if not isinstance(agent.brain, (MLPBrain, LinearInputLayer)):
            raise ParameterError(f"parameter 'agent': {self.source_text()} has a {type(agent.brain).__name__} brain; "
                                 "mlp_brain needs an MLP or LIL agent (narma)")
        self.scale = self.p["input_scale"] or float(agent.config["narma"]["input_scale"])
        self.narma = {**agent.config["narma"], "input_scale": self.scale}  # brain_input's settings
        self.n_in = int(agent.brain.layers[0].in_features if isinstance(agent.brain, MLPBrain)
                        else agent.brain.weight.shape[1])
        body = agent.body
        self.names = mass_dof_names(body.movable_index.tolist())
        self.command = self.joint_state_out(self.names, "effort")
        self.forces = ForceMap(agent)
        self.reader = JointStateReader(input_names(self.n_in))
        self.subscribe_newest(JointState, self.p["topics.task_input"], self._on_input, m.state_qos(self.depth),
                              raw=True)
        self.feed_sim_time()  # from the inputs' stamps
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.pub = self.output(JointState, self.p["topics.force_cmd"], m.command_qos(self.depth))
        self.get_logger().info(f"{type(agent.brain).__name__} of {self.source_text()}: {self.n_in} input(s) × "
                               f"{self.scale:g} → forces on {body.n_movable} movable masses")

    def _on_input(self, data: bytes) -> None:
        started = time.monotonic()
        read = self.reader.read(data)
        if read is None:  # not the usual bytes: deserialized
            msg = deserialize_message(data, JointState)
            ns, u = m.stamp_ns(msg.header.stamp), m.as_array(msg.position)
        else:
            ns, u = read.stamp_ns, read.position
        self.sim_time(ns)
        step = stamp_to_step(0, ns, self.dt_ns)
        if u.size != self.n_in or not np.isfinite(u).all():
            self.warn("bad_input", f"ignored task input of step {step}: {u.tolist()} (expected {self.n_in} "
                      "finite values)")
            return
        force = self.forces(brain_input(u.astype(self.forces.dtype), self.narma))
        self.publish_timed(self.pub, self.command(step, force.reshape(-1)), started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, MlpBrain, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
