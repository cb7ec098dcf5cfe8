"""A fleet in Foxglove or Lichtblick: ``lessmap view`` (WebSocket) and ``lessmap record`` (MCAP).

``model`` (what the viewer knows of each robot: its trajectory, submaps, transitions, the
CovGraph of its current submap; no I/O), ``scene`` (that knowledge as Foxglove messages on
fixed channels), ``feed`` (the lessmap bus to the model and the channels: the robots' frames
for poses, the transitions, the service's states) and ``cli_viz`` (the two commands).
foxglove-sdk (the ``lessmap[viz]`` extra) is imported only when a command runs.
"""
