"""The commands' application work, one module per command: the only place a plugin host
is built (one per run). Imports every layer below it; the CLI calls it."""
