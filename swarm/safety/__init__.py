"""The C3BF-QP safety core: barriers (:mod:`swarm.safety.barriers`), their constraint rows
(:mod:`swarm.safety.constraints`), the filter (:mod:`swarm.safety.filter`), obstacles and the QP
backends (:mod:`swarm.safety.qp`). The math and what each row guarantees: docs/design.md,
"The barrier math"."""
