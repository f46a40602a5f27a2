"""expanded NARMA emulation: streamed input u → MLP (or LIL) forces on the masses.

Nodes: body_sim, task_input, mlp_brain (+ recorder with bag:=DIR). Same processes and parameters as
``bptsb launch narma``; the launch ends (exit 0) when body_sim finishes (after duration:=SECONDS), and
shuts every node down and exits non-zero when any other node exits.

    ros2 launch bptsb_ros narma.launch.py duration:=10 mode:=lockstep bag:=bags/run

Arguments: agent, mode (lockstep|realtime), duration, bag, seed, rate_scale, open_loop_steps,
perturb_at, perturb_sigma, perturb_seed, namespace, log_level, params_file, composed, rviz
(``ros2 launch bptsb_ros narma.launch.py --show-args``).
"""

from bptsb_ros.ros.launch_description import ros_launch_description


def generate_launch_description():
    return ros_launch_description("narma")
