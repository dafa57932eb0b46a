"""Column names of hbench's tidy rows (no heavy imports: the command line loads this at start)."""

#: Identifying columns of a tidy row, in order.
ID_COLUMNS = (
    "cell",
    "method",
    "nonlinearity",
    "plant",
    "p",
    "delay",
    "sigma2",
    "snr_target",
    "run",
    "seed",
)
#: One row per run x method x quantity: identifiers, then the value, then status and error.
TIDY_COLUMNS = (*ID_COLUMNS, "quantity", "value", "true", "snr", "status", "error")
