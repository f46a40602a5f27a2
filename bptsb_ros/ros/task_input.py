"""``task_input``: streams a task's input series on ``task/input``, one value per step.

For NARMA (the only task with an input series) the inputs u_j ~ U(0, 1) come from
``numpy.random.default_rng(seed)`` as in ``NarmaTask.evaluate``, and are held for τ steps by
``bptsb_ros.sim.rollout.held_inputs``, the function the offline episodes use: step 0 and steps 1…τ
carry u_0, steps jτ+1…(j+1)τ carry u_j.
On each ``/clock`` tick t_k it publishes the raw input in force at step k (dimensionless; the MLP
brain applies the input scale).
"""

from __future__ import annotations

import sys
import time

from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from bptsb_ros.interface.params import Param, ParameterError
from bptsb_ros.interface.topics import input_names
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.sim.inputs import narma_inputs
from bptsb_ros.sim.rollout import held_inputs

NODE = "task_input"
PARAMS = (
    Param("input_seed", -1, "seed of the input series; -1: the agent config's narma.eval_seed (the held-out "
          "evaluation sequence)", "int", minimum=-1),
    Param("tau", 0, "steps each input is held; 0: the agent config's narma.tau", "int", minimum=0),
) + topic_params(("clock", "task_input"))


class TaskInput(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        cfg = self.agent.config
        if self.agent.task != "narma":
            raise ParameterError(f"parameter 'agent': task_input streams the NARMA input; {self.source_text()} is a "
                                 f"{self.agent.task} agent")
        self.seed = self.p["input_seed"] if self.p["input_seed"] >= 0 else int(cfg["narma"]["eval_seed"])
        self.tau = self.p["tau"] or int(cfg["narma"]["tau"])
        self._hold(int(cfg["narma"]["n_inputs"]))
        self.names = input_names(1)
        self.command = self.joint_state_out(self.names, "position")
        self.subscribe_newest(Clock, self.p["topics.clock"], self._on_clock, m.state_qos(self.depth), raw=True)
        self.feed_sim_time()
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.pub = self.output(JointState, self.p["topics.task_input"], m.command_qos(self.depth))
        self.get_logger().info(f"NARMA input u ~ U(0, 1), seed {self.seed}, held {self.tau} steps")

    def _hold(self, n_inputs: int) -> None:
        """The first ``n_inputs`` inputs of the series, held: ``self.held[k]`` is the input in force at step k
        for steps 0..n_inputs·τ (the series is a prefix of any longer one with the same seed)."""
        self.series = narma_inputs(self.seed, n_inputs)
        self.held = held_inputs(self.series, self.tau, n_inputs * self.tau)

    def _on_clock(self, data: bytes) -> None:
        started = time.monotonic()
        step = self.clock_step(data)
        if step >= self.held.size:
            self._hold(max(2 * self.series.size, step // self.tau + 1))
        value = self.held[step : step + 1]
        self.publish_timed(self.pub, self.command(step, value), started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, TaskInput, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
