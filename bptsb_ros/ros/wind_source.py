"""``wind_source``: the periodic headwind of the locomotion switching task, in lockstep with the body.

On each ``/clock`` tick t_k it publishes on ``env/wind`` the wind in force at step k (stamped t_k):
F_wind along x while :func:`bptsb_ros.tasks.locomotion.wind_blowing` says the wind blows at step k (calm for
the first half of every period, blowing for the second), else 0 — the schedule offline training and
simulation use. ``body_sim`` with ``wait_for: [..., wind]`` integrates step k only with the wind of step k, so
the live run equals the offline one. Force and period default to the agent's ``locomotion.wind_force`` and
``locomotion.wind_period``.
"""

from __future__ import annotations

import math
import sys
import time

from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock

from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import BrainNode, topic_params
from bptsb_ros.ros.params import Param, ParameterError
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.tasks.locomotion import wind_blowing

NODE = "wind_source"
PARAMS = topic_params(("clock", "wind")) + (
    Param("force", "", "F_wind while the wind blows [N, along x]; empty: the agent's locomotion.wind_force", "str"),
    Param("period", "", "wind cycle [s] (calm half, blowing half; 0: always blowing); empty: the agent's "
          "locomotion.wind_period", "str"),
)


def _number(name: str, text: str, default: float) -> float:
    if not text.strip():
        return float(default)
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"parameter '{name}' must be a number or empty, got {text!r}") from None
    if not math.isfinite(value):
        raise ParameterError(f"parameter '{name}' must be finite, got {text!r}")
    return value


class WindSource(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        loc = self.agent.config.get("locomotion", {})
        self.force = _number("force", self.p["force"], loc.get("wind_force", 0.0))
        self.period = _number("period", self.p["period"], loc.get("wind_period", 0.0))
        if self.period < 0:
            raise ParameterError(f"parameter 'period' must be >= 0, got {self.period}")
        self.pub = self.output(Vector3Stamped, self.p["topics.wind"], m.command_qos(self.depth))
        self.create_subscription(Clock, self.p["topics.clock"], self._on_clock, m.state_qos(self.depth))
        self.get_logger().info(f"headwind {self.force:g} N along x, period {self.period:g} s "
                               f"({'calm half, blowing half' if self.period > 0 else 'always blowing'})")

    def wind_at(self, step: int) -> float:
        """F_wind along x in force at ``step`` [N]."""
        return self.force if bool(wind_blowing([step], self.agent.dt, self.period)[0]) else 0.0

    def _on_clock(self, msg: Clock) -> None:
        started = time.monotonic()
        step = m.step_of(msg.clock, self.dt_ns)
        out = Vector3Stamped()
        out.header.stamp = m.stamp(step, self.dt_ns)
        out.vector.x = self.wind_at(step)
        self.publish_timed(self.pub, out, started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, WindSource, args)


if __name__ == "__main__":
    sys.exit(main())
