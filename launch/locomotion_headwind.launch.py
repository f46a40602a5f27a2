"""caterpillar locomotion under a periodic headwind: SWG rest lengths and the wind, in lockstep.

Nodes: body_sim, swg_brain, wind_source (+ recorder with bag:=DIR). Same processes and parameters as
``bptsb launch locomotion_headwind``; the launch ends when body_sim exits (after duration:=SECONDS).

    ros2 launch bptsb_ros locomotion_headwind.launch.py duration:=10 mode:=lockstep bag:=bags/run

Arguments: agent, mode (lockstep|realtime), duration, bag, seed, rate_scale, open_loop_steps,
perturb_at, perturb_sigma, perturb_seed, namespace, log_level, params_file, composed, rviz
(``ros2 launch bptsb_ros locomotion_headwind.launch.py --show-args``).
"""

from bptsb_ros.ros.launch_description import ros_launch_description


def generate_launch_description():
    return ros_launch_description("locomotion_headwind")
