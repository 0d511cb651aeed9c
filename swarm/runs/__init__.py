"""Running a swarm and reading its runs: launch, record, report, view, compare, sweep (the shell around the core)."""
