"""ROS 2 and ROS 1: landmark detections in, lessmap frames out, transitions back out.

``msgtypes`` (the message definitions lessmap knows, registered from their ``.msg`` text in a
rosbags type store), ``extract`` (which fields of a message are the feature IDs, and the
robot's pose), ``convert`` (one decoded message to one frame, counting what could not be
converted), ``bridge`` (live: rmw_zenoh topics to robot publishers, ``lessmap ros``) and
``bags`` (offline: rosbag2 and ROS 1 bags to a frames file, ``lessmap import``). Back out:
``outgoing`` (transitions as ``lessmap_msgs`` messages, the ament package in
``lessmap_msgs/``), ``rmw`` (rmw_zenoh's keys, tokens and attachment) and ``publisher``.
Only ``bridge`` and ``publisher`` touch Zenoh; rosbags is imported when a command runs,
never by ``--help``.
"""
