"""``swg_brain``: rest-length commands l·(1 + A sin(ω t_k + φ)) from a trained sine-wave generator.

On each ``/clock`` tick t_k it publishes the rest lengths in force at step k, computed by
``bptsb_ros.sim.rollout.swg_rest_lengths`` — the function the offline open-loop simulation uses — for blocks of
steps at a time (:class:`~bptsb_ros.live.inference.SwgTable`).
"""

from __future__ import annotations

import sys
import time

from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.interface.params import ParameterError
from bptsb_ros.interface.topics import spring_names
from bptsb_ros.live.inference import SwgTable
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.runtime import StopFlag, run_node

NODE = "swg_brain"
PARAMS = topic_params(("clock", "rest_length_cmd"))


class SwgBrain(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        if not isinstance(self.agent.brain, SineWaveGenerator):
            raise ParameterError(f"parameter 'agent': {self.source_text()} has a {type(self.agent.brain).__name__} "
                                 "brain; swg_brain needs an SWG agent (lissajous or locomotion)")
        self.names = spring_names(self.agent.body.topology.n_springs)
        self.command = self.joint_state_out(self.names, "position")
        self.table = SwgTable(self.agent.body, self.agent.brain)
        self.subscribe_newest(Clock, self.p["topics.clock"], self._on_clock, m.state_qos(self.depth), raw=True)
        self.feed_sim_time()
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.pub = self.output(JointState, self.p["topics.rest_length_cmd"], m.command_qos(self.depth))
        self.get_logger().info(f"SWG of {self.source_text()}: {len(self.names)} springs, "
                               f"ω = {self.agent.brain.omega:.6g} rad/s")

    def _on_clock(self, data: bytes) -> None:
        started = time.monotonic()
        step = self.clock_step(data)
        self.publish_timed(self.pub, self.command(step, self.table(step)), started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, SwgBrain, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
