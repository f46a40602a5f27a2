"""The live loop without ROS: what the nodes of :mod:`bptsb_ros.ros` do, as plain Python that tests drive directly.

* ``body_core`` — :class:`~bptsb_ros.live.body_core.BodyCore`: the live body's intake (commands, wind,
  perturbations, resets, stamped with steps), its step (``MSDN.step``), divergence recovery, counters and run summary;
* ``body_loop`` — :class:`~bptsb_ros.live.body_loop.BodyLoop`: the lockstep and realtime step loops, awaiting
  commands and the recorder, through a :class:`~bptsb_ros.live.body_loop.BodyPort` (the node, or a fake in tests);
* ``body_params`` — the body's parameter specs; ``summary`` — the run summary as text and JSON; ``channels`` —
  command validation, buffering and timing statistics; ``safety`` — command bounds, the publisher rule, divergence
  recovery;
* ``sim_control`` — :class:`~bptsb_ros.live.sim_control.SimControl`: pause, resume, step N and reset of the body
  (``body_sim``'s services) and their semantics in both timing modes;
* ``newest`` — :class:`~bptsb_ros.live.newest.Newest` and :func:`~bptsb_ros.live.newest.pump`: a brain that fell
  behind answers the newest tick of a backlog and drops the stale ones;
* ``feedback`` — what ``feedback_brain`` commands: which step the clock or the state answers, and the layer's output;
* ``loops`` and ``mnist_loop`` — the loops ``bptsb launch`` and ``launch/*.launch.py`` start (nodes, parameters,
  wiring), and the MNIST image stream's plan.

Nothing here imports rclpy or message types; ``body_sim`` and the brains convert messages and call these.
"""
