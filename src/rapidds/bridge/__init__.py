"""The border to a real cell: ROS 2 messages (CDR), rosbag2 bags (MCAP, SQLite) and a live Zenoh
link. Nothing outside this package knows CDR, MCAP or Zenoh; nothing inside it knows a world by
name (joint and body-point names come from the world)."""
