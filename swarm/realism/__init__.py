"""One model of the world's imperfections, for both simulators (the PyBullet world process
and the in-process closed loop): pure code, no I/O.

* :mod:`~swarm.realism.aero`: downwash between drones, rotor drag, ground effect;
* :mod:`~swarm.realism.motors`: rotor-speed lag (up and down), per-drone thrust and mass factors;
* :mod:`~swarm.realism.wind`: a steady wind and Dryden gusts;
* :mod:`~swarm.realism.plant`: the three above as one step;
* :mod:`~swarm.realism.sensing`: motion-capture frames and the agent's estimator;
* :mod:`~swarm.realism.comms`: the delay and loss of each message;
* :mod:`~swarm.realism.settings`: the ``world.realism`` config section and its presets;
* :mod:`~swarm.realism.rng`: the counter-based draws all of them make.

Each model cites its source and fitted range; docs/design.md, "The model of the world".

How a simulator calls it (``r = cfg.world.realism``; skip all of it when ``r.ideal``)::

    # once, at the start (n drones in a fixed order; nominal[i] their airframes)
    plant = r.plant(nominal, dt_s=1 / physics_hz, seed=cfg.seed)
    #   build drone i's body (PyBullet, RK4) from plant.airframes[i]; its controllers keep nominal[i]
    mocap = r.mocap(n, cfg.seed)               # with r.sensing.enabled
    comms = r.comms_model(cfg.seed, tick_s=1 / control_hz)

    # every physics step, from time t (true states x_w, v_w, R, q of all drones, stacked)
    frames = mocap.step(t, x_w, q)             # the frames that arrived by t: frame f to drone f.drone's agent
    out = plant.step(x_w, v_w, R, f_cmd_N)     # f_cmd_N (n, 4): the thrusts the controllers ask
    world.apply_rotors_all(names, out.f_N, states)                   # in place of f_cmd_N
    world.apply_external_all(names, out.force_w, out.torque_b, states)
    #   RK4: swarm.model.step_rk4(model_i, state_i, out.f_N[i], dt, out.force_w[i], out.torque_b[i])

    # every control tick k, in each agent (one Estimator each; truth never reaches it)
    est = r.estimator(start_w, q0)             # once
    for f in my_frames: est.frame(f)
    e = est.estimate(t)                        # e.x_w, e.v_w, e.q, e.Omega_b: the state to act on
    ...                                        # filter, command the thrust vector F_w
    est.command(t, F_w / nominal_mass - g e3)  # the acceleration it commands from t on

    # every message (state, bundle, command) sent at tick k
    d = comms.fate(sender_id, receiver_id, MessageKind.STATE, k)  # LOST, or delivered at tick k + d
    line.put(k, d, msg); ...; line.due(k)      # a DelayLine per receiver holds it until then

The world's drone order, the agents' ids and the seed are all a fate, a frame or a gust
depends on, so a lockstep run repeats bit for bit.
"""
