"""``hbench sweep``: the Hydra app (one job = one cell), its validated configuration, the callbacks
that aggregate tables, and the adapter to Hydra."""
