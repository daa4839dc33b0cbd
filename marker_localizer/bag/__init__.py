"""rosbag2 I/O: record a simulated flight, replay a bag offline, play a bag live.

* :func:`~marker_localizer.bag.record.record_flight` (``marker-localizer simulate``):
  fly :class:`~marker_localizer.synthetic.flight.FlightSimulator` into a bag
  with images, camera_info, /tf_static and the exact truth.
* :func:`~marker_localizer.bag.replay.replay_bag` (``replay``): every
  frame through the node's :class:`~marker_localizer.ros.processing.FrameProcessor`,
  results and /diagnostics into a new bag, accuracy against the truth.
* :func:`~marker_localizer.bag.play.play_bag` (``play``): publish a bag
  on its topics with rclpy, like ``ros2 bag play``.

Importing this package needs rclpy and the ROS message packages, as
:mod:`marker_localizer.ros` does; bags are read and written with ``rosbags``
(:mod:`marker_localizer.bag.io`). The commands' arguments and summaries are
:mod:`marker_localizer.cli.bag`'s.
"""
