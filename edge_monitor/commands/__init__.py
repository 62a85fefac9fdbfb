"""One module per ``edge-monitor`` subcommand; each exposes ``add_parser(subparsers)``."""
