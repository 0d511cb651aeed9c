"""The ROS 2 names of a run's Zenoh keys, as rmw_zenoh spells them: the message types
(:mod:`.interfaces`), the graph's liveliness tokens and key expressions (:mod:`.graph`) and the
run's topics (:mod:`.topics`). Below the transport, which grants the keys, and the ROS 2 bridge
(``swarm.ros2``), which speaks on them."""
