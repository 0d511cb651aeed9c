"""The swarm as ROS 2 topics over the run's Zenoh, the way rmw_zenoh maps them (docs/ros2.md).

``convert``: swarm records to ROS 2 messages and back (pure); ``goals``: a new goal for an
agent, as a new path (pure) and its inbox; ``bridge``: the bridge process; ``participant``: a
ROS 2 participant's environment. The ROS 2 names they use (message types, rmw_zenoh's keys, a
run's topics) are ``swarm.net.ros2``'s; a run as a ROS 2 bag is ``swarm.runs.bag``.
"""
