"""c3swarm: the pure core (model, barriers, safety filter, reference control)."""
