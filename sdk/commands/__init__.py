"""CLI subcommands of the SDK (runtime side: no torch)."""
