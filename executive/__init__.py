"""The executive: configuration, cell assembly, the task state machine and runner, the run journal, the
daemon (local HTTP API) and the `kitchenbot` command line."""
