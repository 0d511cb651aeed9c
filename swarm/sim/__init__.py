"""The simulator's plant, one for every shell: PyBullet bodies (:mod:`swarm.sim.physics`) and the
stepper that flies each simulated drone's command through its link (:mod:`swarm.sim.stepper`).
The world process wires it to Zenoh; the offline loop (``swarm.offline.closed_loop``) calls it
in-process."""
