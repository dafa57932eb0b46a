"""Records read from measured files (CSV, Parquet, plant logs) and written back."""
