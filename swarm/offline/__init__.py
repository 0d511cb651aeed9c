"""What runs without the swarm's processes: the in-process closed loop, the ORCA baseline,
scenario generation and a run's metrics."""
