"""What a run asks of the operating system: the process settings a cell computes under, size limits
against a memory budget, and files written whole or not at all."""
