"""``hbench reproduce``: the paper's Section 6 example at every noise level beside the published
tables."""
