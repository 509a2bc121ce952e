"""Benchmarks that print numbers (`kitchenbot bench WHAT`). They assemble whole cells, so they live at the top,
beside the executive; each module exposes ``register(subparsers)`` (one sub-subcommand per benchmark)."""
