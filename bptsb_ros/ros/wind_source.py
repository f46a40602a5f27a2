"""``wind_source``: a wind schedule on ``env/wind``, in lockstep with the body.

On each ``/clock`` tick t_k it publishes on ``env/wind`` the wind in force at step k (stamped t_k), from a
:class:`bptsb_ros.sim.wind_schedule.WindSchedule` — the schedule offline training and simulation use. ``body_sim``
with ``wait_for: [..., wind]`` integrates step k only with the wind of step k, so a live run equals the offline
one (loops ``locomotion_headwind`` and ``lissajous_switching``).

The schedule is the agent's own unless ``schedule`` says otherwise (``wind_schedule.for_agent``): a switching
agent's switching wind (segments of whole SWG periods, random switch phases), a Lissajous agent's the same, a
locomotion agent's periodic headwind. Every other parameter overrides one setting of it; empty / default: keep it.
"""

from __future__ import annotations

import sys
import time
from dataclasses import fields

from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock

from bptsb_ros.interface.params import Param, ParameterError
from bptsb_ros.live.safety import DEFAULT_MAX_WIND
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.sim.wind_schedule import KINDS, WindSchedule, WindScheduleError, for_agent, read_table

NODE = "wind_source"
PARAMS = topic_params(("clock", "wind")) + (
    Param("schedule", "", "wind schedule: constant, periodic, switching or file; empty: the agent's own (switching "
          "for Lissajous agents, the periodic headwind for locomotion agents)", "str", choices=("",) + KINDS),
    Param("force", "", "F_x while the wind blows [N]; empty: the schedule's (the agent's locomotion.wind_force, or "
          "F_wind = 1 for switching)", "optional_float"),
    Param("force_y", "", "F_y while the wind blows [N]; empty: the schedule's", "optional_float"),
    Param("period", "", "periodic: wind cycle [s] (calm half, blowing half; 0: always blowing); switching: the SWG "
          "period [s] segments are counted in; empty: the agent's", "optional_float"),
    Param("schedule_seed", 0, "switching: seed of the segment lengths and switch phases", "int"),
    Param("hold_periods", "", "switching: 'lo,hi' whole periods per segment (inclusive); empty: 3,8 (the training's)",
          "str"),
    Param("timing", "", "switching: switch phase n/100 of a period: random, fixed (n = 0) or n in 0..99; empty: "
          "random", "str"),
    Param("start_on", False, "switching: the first segment blows", "bool"),
    Param("file", "", "file: CSV table with header t,fx,fy (t [s] ascending; the last row with t <= k·dt is in force "
          "at step k)", "str"),
    Param("max_wind", DEFAULT_MAX_WIND, "body_sim's max_wind [N] (bptsb launch passes it): a schedule with a force "
          "component beyond it is refused at startup, since the body would reject every such wind", "float",
          positive=True),
)


def _number(value: float | str) -> float | None:
    """An ``optional_float`` parameter's value: None when not given ('')."""
    return None if value == "" else float(value)


def schedule_from_parameters(config: dict, extra: dict, p: dict, dt: float = 0.01) -> WindSchedule:
    """The wind schedule of a ``wind_source`` from its parameters ``p`` and the agent's config and checkpoint extras
    (``dt``: the agent's time step [s]). Raises ParameterError naming the parameter."""
    try:
        base = for_agent(config, extra)
    except WindScheduleError:
        base = None
    kind = p["schedule"] or (base.kind if base else "")
    if not kind:
        raise ParameterError(f"parameter 'schedule': a {config.get('task')} agent has no wind of its own; choose "
                             f"one of {', '.join(KINDS)}")
    fx, fy, period = _number(p["force"]), _number(p["force_y"]), _number(p["period"])
    hold = None
    if p["hold_periods"].strip():
        parts = p["hold_periods"].split(",")
        if len(parts) != 2 or not all(x.strip().isascii() and x.strip().isdigit() for x in parts):
            raise ParameterError(f"parameter 'hold_periods' must be 'lo,hi' (two whole numbers), got "
                                 f"{p['hold_periods']!r}")
        hold = (int(parts[0]), int(parts[1]))
    if kind == "file" and not p["file"]:
        raise ParameterError("parameter 'file': the file schedule needs a CSV table (t,fx,fy)")
    settings = schedule_settings(base) if base is not None and base.kind == kind else {"kind": kind}
    force = settings.get("force", (0.0, 0.0))
    overrides = {"force": (force[0] if fx is None else fx, force[1] if fy is None else fy), "period": period,
                 "seed": p["schedule_seed"], "hold_periods": hold, "timing": p["timing"] or None,
                 "start_on": p["start_on"]}
    settings.update({k: v for k, v in overrides.items() if v is not None})
    limit = p["max_wind"]
    try:
        if kind == "file":
            settings.update(table=read_table(p["file"], max_force=limit), source=p["file"])
        schedule = WindSchedule(**settings)
        schedule.force_at(0, dt)  # the period in steps is checked here, at startup
    except WindScheduleError as err:
        raise ParameterError(f"wind schedule: {err}") from None
    if kind != "file":
        for name, value in (("force", schedule.force), ("calm", schedule.calm)):
            if max(abs(value[0]), abs(value[1])) > limit:
                raise ParameterError(f"wind schedule: its {name} ({value[0]:g}, {value[1]:g}) N is beyond the "
                                     f"body's max_wind of {limit:g} N per component (every wind would be rejected)")
    return schedule


def schedule_settings(schedule: WindSchedule) -> dict:
    """The fields of ``schedule`` as keyword arguments of WindSchedule."""
    return {f.name: getattr(schedule, f.name) for f in fields(schedule) if not f.name.startswith("_")}


class WindSource(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        extra: dict = {}
        if self.trained:
            from bptsb_ros.training.checkpoint import read_checkpoint

            extra = read_checkpoint(self.p["agent"])["extra"]
        self.schedule = schedule_from_parameters(self.agent.config, extra, self.p, self.agent.dt)
        self.subscribe_newest(Clock, self.p["topics.clock"], self._on_clock, m.state_qos(self.depth), raw=True)
        self.feed_sim_time()
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.pub = self.output(Vector3Stamped, self.p["topics.wind"], m.command_qos(self.depth))
        self.get_logger().info(f"wind: {self.schedule.describe()}")

    def wind_at(self, step: int) -> tuple[float, float]:
        """(F_x, F_y) in force at ``step`` [N]."""
        return self.schedule.force_at(step, self.agent.dt)

    def _on_clock(self, data: bytes) -> None:
        started = time.monotonic()
        step = self.clock_step(data)
        out = Vector3Stamped()
        out.header.stamp = m.stamp(step, self.dt_ns)
        out.vector.x, out.vector.y = self.wind_at(step)
        self.publish_timed(self.pub, out, started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=runs/x ...``), default sys.argv."""
    return run_node(NODE, WindSource, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
