"""The runtime's wiring: Zenoh transport and keys, message schemas, access control, interest
cells, neighbour tables, state records and bundles."""
