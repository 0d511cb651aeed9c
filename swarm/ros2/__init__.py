"""The swarm as ROS 2 topics over the run's Zenoh, the way rmw_zenoh maps them (docs/ros2.md).

``interfaces``: the message types, their RIHS01 hashes and the CDR codec (rosbags);
``graph``: rmw_zenoh's key expressions, liveliness tokens and attachment (pure);
``topics``: which topics a run has (pure); ``convert``: swarm records to ROS 2 messages
and back (pure); ``goals``: a new goal for an agent, as a new path (pure) and its inbox;
``bridge``: the bridge process; ``bag``: a run as a ROS 2 bag.
"""
