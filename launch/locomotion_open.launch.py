"""caterpillar locomotion, open loop: SWG rest lengths, gravity and ground.

Nodes: body_sim, swg_brain (+ recorder with bag:=DIR). Same processes and parameters as
``bptsb launch locomotion_open``; the launch ends (exit 0) when body_sim finishes (after duration:=SECONDS), and
shuts every node down and exits non-zero when any other node exits.

    ros2 launch bptsb_ros locomotion_open.launch.py duration:=10 mode:=lockstep bag:=bags/run

Arguments: agent, mode (lockstep|realtime), duration, bag, seed, rate_scale, open_loop_steps,
perturb_at, perturb_sigma, perturb_seed, namespace, log_level, params_file, composed, rviz
(``ros2 launch bptsb_ros locomotion_open.launch.py --show-args``).
"""

from bptsb_ros.ros.launch_description import ros_launch_description


def generate_launch_description():
    return ros_launch_description("locomotion_open")
