"""Lissajous switching by wind: SWG rest lengths and the agent's wind schedule (on and off at random times), lockstep.

Nodes: body_sim, swg_brain, wind_source (+ recorder with bag:=DIR). Same processes and parameters as
``bptsb launch lissajous_switching``; the launch ends when body_sim exits (after duration:=SECONDS).

    ros2 launch bptsb_ros lissajous_switching.launch.py duration:=10 mode:=lockstep bag:=bags/run

Arguments: agent, mode (lockstep|realtime), duration, bag, seed, rate_scale, open_loop_steps,
perturb_at, perturb_sigma, perturb_seed, namespace, log_level, params_file, composed, rviz
(``ros2 launch bptsb_ros lissajous_switching.launch.py --show-args``).
"""

from bptsb_ros.ros.launch_description import ros_launch_description


def generate_launch_description():
    return ros_launch_description("lissajous_switching")
