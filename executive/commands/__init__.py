"""One module per `kitchenbot` subcommand; each exposes `register(subparsers)`."""
