"""ROS 2 interop without a ROS installation.

- ``msgs/``: the shipped ``rfsas_msgs`` (version 1) and ``radar_msgs`` definitions;
- :mod:`~rfsas_hw.ros2.types`: the typestore (Jazzy standard types + shipped), CDR;
- :mod:`~rfsas_hw.ros2.topics`: the topic table with types and QoS;
- :mod:`~rfsas_hw.ros2.scene`: rfsas records → messages (frames per REP-103/105);
- :mod:`~rfsas_hw.ros2.sink`: the scene as a bearing listener and a backend sink;
- :mod:`~rfsas_hw.ros2.bag`: MCAP file and rosbag2 directory writers;
- :mod:`~rfsas_hw.ros2.export`: JSON-lines runs → MCAP / rosbag2;
- :mod:`~rfsas_hw.ros2.dds`: Cyclone DDS publisher and odometry subscription;
- :mod:`~rfsas_hw.ros2.foxglove_live`: the Foxglove WebSocket server;
- :mod:`~rfsas_hw.ros2.outputs`: ``--out run.mcap`` for the commands.

Every optional dependency (the ``ros2`` extra) is imported when first used.
"""
