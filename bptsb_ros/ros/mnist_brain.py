"""``mnist_brain``: the brain of the live MNIST loop — an image in, the body's initial displacements out.

Each ``camera/image`` (``sensor_msgs/Image``, mono8, 28 × 28) goes through the trained system's brain exactly as in
training and offline drawing: pixels / 255 (``tasks.mnist_live.pixels``), then ``ImageToBody.displacement``. The
result goes on ``body/reset`` (``sensor_msgs/JointState``): names ``mass_<i>/x``, ``mass_<i>/y`` of the movable
masses (global indices), ``position`` = displacement from the layout [m] (the CMP's row is zero), ``header.stamp`` =
the image's stamp, the step at which ``body_sim`` resets the body to it and releases it. ``agent`` must be an MNIST
system file (``systems/<name>.pt``). An image of another encoding or size is refused with a log line (no reset).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch
from sensor_msgs.msg import Image, JointState

from bptsb_ros.interface.params import ParameterError
from bptsb_ros.interface.topics import mass_dof_names
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.tasks.drawing import ImageToBody
from bptsb_ros.tasks.mnist_live import IMAGE_SIDE, pixels

NODE = "mnist_brain"
PARAMS = topic_params(("image", "reset_cmd"))


def image_problem(msg: Image) -> str | None:
    """Why ``msg`` is not a mono8 28 × 28 image (with 28-byte rows), or None."""
    if msg.encoding != "mono8":
        return f"encoding {msg.encoding!r}, expected 'mono8'"
    if (msg.height, msg.width) != (IMAGE_SIDE, IMAGE_SIDE):
        return f"{msg.height} x {msg.width} pixels, expected 28 x 28"
    if msg.step != IMAGE_SIDE or len(msg.data) != IMAGE_SIDE * IMAGE_SIDE:
        return f"row step {msg.step} and {len(msg.data)} bytes, expected 28 and 784"
    return None


class MnistBrain(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        if not isinstance(self.agent.brain, ImageToBody):
            raise ParameterError(f"parameter 'agent': mnist_brain needs an MNIST system file (systems/<name>.pt); "
                                 f"{self.source_text()} is a {self.agent.task} agent")
        self.system: ImageToBody = self.agent.brain
        self.names = mass_dof_names(self.system.body.movable_index.tolist())
        self.create_subscription(Image, self.p["topics.image"], self._on_image, m.state_qos(self.depth))
        self.feed_sim_time()  # from the images' stamps
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.pub = self.output(JointState, self.p["topics.reset_cmd"], m.command_qos(self.depth))
        self.get_logger().info(f"{self.system.spec.name}: images -> displacements of {self.system.n_driven} masses")

    def _on_image(self, msg: Image) -> None:
        started = time.monotonic()
        problem = image_problem(msg)
        if problem:
            self.warn("bad_image", f"refused camera image: {problem}; no reset sent")
            return
        self.sim_time(m.stamp_ns(msg.header.stamp))
        step = m.step_of(msg.header.stamp, self.dt_ns)
        image = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(1, IMAGE_SIDE, IMAGE_SIDE)
        with torch.no_grad():
            disp = self.system.displacement(pixels(image))[0]
        out = m.joint_state(step, self.dt_ns, self.names, position=disp.double().numpy().reshape(-1))
        self.publish_timed(self.pub, out, started)


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p agent:=systems/x.pt``), default sys.argv."""
    return run_node(NODE, MnistBrain, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
