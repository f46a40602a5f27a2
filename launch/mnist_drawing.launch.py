"""see a digit, draw it: streamed MNIST images -> the system's brain -> the body's initial displacements, in lockstep.

Nodes: body_sim, image_streamer, mnist_brain (+ recorder with bag:=DIR). Same processes and parameters as
``bptsb launch mnist_drawing``; the launch ends when body_sim exits (after count episodes of episode_steps steps,
or duration:=SECONDS).

    ros2 launch bptsb_ros mnist_drawing.launch.py agent:=runs/mnist-drawing/systems/mlp-multiple_circle-37.pt \
        images:=data/mnist/t10k-images-idx3-ubyte.gz labels:=data/mnist/t10k-labels-idx1-ubyte.gz count:=10 \
        bag:=bags/mnist

Arguments: agent, images, labels, first, count, episode_steps, mode (lockstep only), duration, bag, seed, rate_scale,
open_loop_steps, perturb_at, perturb_sigma, perturb_seed, namespace, log_level, params_file, composed, rviz
(``ros2 launch bptsb_ros mnist_drawing.launch.py
--show-args``).
"""

from bptsb_ros.ros.launch_description import ros_launch_description


def generate_launch_description():
    return ros_launch_description("mnist_drawing")
