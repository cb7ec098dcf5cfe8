"""ROS 2 and ROS 1 input: landmark detections in, lessmap frames out (``lessmap[ros]``).

``msgtypes`` (the message definitions lessmap knows, registered from their ``.msg`` text in a
rosbags type store), ``extract`` (which fields of a message are the feature IDs, and the
robot's pose), ``convert`` (one decoded message to one frame, counting what could not be
converted), ``bridge`` (live: rmw_zenoh topics to robot publishers, ``lessmap ros``) and
``bags`` (offline: rosbag2 and ROS 1 bags to a frames file, ``lessmap import``). Only
``bridge`` touches Zenoh; rosbags is imported when a command runs, never by ``--help``.
"""
