"""caterpillar locomotion, closed loop: the fitted feedback layer drives the body.

Nodes: body_sim, feedback_brain (+ recorder with bag:=DIR). Same processes and parameters as
``bptsb launch locomotion_closed``; the launch ends (exit 0) when body_sim finishes (after duration:=SECONDS), and
shuts every node down and exits non-zero when any other node exits.

    ros2 launch bptsb_ros locomotion_closed.launch.py agent:=runs/NAME duration:=10 mode:=lockstep bag:=bags/run

Arguments: agent (required: a trained agent with a fitted feedback layer), mode (lockstep|realtime), duration,
bag, seed, rate_scale, open_loop_steps,
perturb_at, perturb_sigma, perturb_seed, namespace, log_level, params_file, composed, rviz
(``ros2 launch bptsb_ros locomotion_closed.launch.py --show-args``).
"""

from bptsb_ros.ros.launch_description import ros_launch_description


def generate_launch_description():
    return ros_launch_description("locomotion_closed")
