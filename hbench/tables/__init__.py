"""The contract's tables aggregated from tidy rows, the report's headline and summary tables, and
their provenance."""
