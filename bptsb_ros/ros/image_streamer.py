"""``image_streamer``: the camera of the live MNIST loop — one test image per episode, in lockstep with the body.

On each ``/clock`` tick t_k with k = i·E (E = ``episode_steps``, i < ``count``) it publishes image i of the stream
on ``camera/image`` (``sensor_msgs/Image``, mono8, 28 × 28, step 28, ``header.stamp`` = t_k, frame ``camera``) and
its label on ``camera/label`` (``sensor_msgs/JointState``, name ``label``, position [digit], same stamp). After
``count`` images it publishes nothing more (``body_sim`` ends the run by its duration). The stream is a pair of IDX
files, gzipped or not (``tasks.mnist_live.read_stream``); the schedule is ``tasks.mnist_live.shown_image``.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, JointState

from bptsb_ros.data.mnist import MnistError
from bptsb_ros.interface.params import Param, ParameterError
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.brain_node import COMMON_PARAMS, BrainNode, topic_params
from bptsb_ros.ros.runtime import StopFlag, run_node
from bptsb_ros.tasks.mnist_live import IMAGE_SIDE, default_episode_steps, read_stream, shown_image

NODE = "image_streamer"
PARAMS = (
    Param("images", "", "IDX file of the images (n, 28, 28) uint8, gzipped if it ends in .gz (e.g. "
          "t10k-images-idx3-ubyte.gz)", "str"),
    Param("labels", "", "IDX file of their labels (n,) uint8, digits 0-9", "str"),
    Param("first", 0, "index of the first image streamed", "int", minimum=0),
    Param("count", 0, "images streamed, one per episode (0: every image from 'first' on)", "int", minimum=0),
    Param("episode_steps", 0, "steps per episode E: image i is shown at step i·E; 0: the longest digit target's "
          "steps + 1 at the agent's time step", "int", minimum=0),
    Param("frame_id", "camera", "frame_id of the images and labels", "str"),
) + topic_params(("clock", "image", "label"))


def image_msg(step: int, dt_ns: int, pixels: np.ndarray, frame_id: str) -> Image:
    """A mono8 28 × 28 ``sensor_msgs/Image`` of ``pixels`` (28, 28) uint8, stamped at step ``step``."""
    msg = Image()
    msg.header.stamp = m.stamp(step, dt_ns)
    msg.header.frame_id = frame_id
    msg.height = msg.width = msg.step = IMAGE_SIDE
    msg.encoding = "mono8"
    msg.is_bigendian = 0
    msg.data = np.ascontiguousarray(pixels, dtype=np.uint8).tobytes()
    return msg


class ImageStreamer(BrainNode):
    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE, stop, PARAMS)
        p = self.p
        if not p["images"] or not p["labels"]:
            raise ParameterError("parameters 'images' and 'labels': give both IDX files of the stream")
        try:
            self.images, self.labels = read_stream(p["images"], p["labels"], p["first"], p["count"])
        except MnistError as err:
            raise ParameterError(f"parameters 'images'/'labels'/'first'/'count': {err}") from None
        self.episode_steps = p["episode_steps"] or default_episode_steps(self.agent.dt)
        self.frame = p["frame_id"]
        self.names = ["label"]
        self.create_subscription(Clock, p["topics.clock"], self._on_clock, m.state_qos(self.depth), raw=True)
        self.feed_sim_time()
        self.await_inputs()  # then the outputs: their publishers tell the body this node hears its inputs
        self.image_pub = self.output(Image, p["topics.image"], m.command_qos(self.depth))
        self.label_pub = self.output(JointState, p["topics.label"], m.command_qos(self.depth))
        self.get_logger().info(f"streaming {len(self.labels)} images from {p['images']} (first {p['first']}), one "
                               f"every {self.episode_steps} steps")

    def _on_clock(self, data: bytes) -> None:
        started = time.monotonic()
        step = self.clock_step(data)
        index = shown_image(step, self.episode_steps, len(self.labels))
        if index is None:
            return
        label = m.joint_state(step, self.dt_ns, self.names, position=np.array([float(self.labels[index])]),
                              frame_id=self.frame)
        # the image waits (once) for min_subscribers (the brain, the recorder); the label only goes to the recorder
        self.publish_timed(self.image_pub, image_msg(step, self.dt_ns, self.images[index], self.frame), started)
        self.label_pub.publish(label)
        self.sent += 1


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p images:=... -p labels:=...``), default sys.argv."""
    return run_node(NODE, ImageStreamer, args, params=COMMON_PARAMS + PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
