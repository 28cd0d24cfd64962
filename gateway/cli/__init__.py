"""The `cnc-gateway` command line (`gateway.cli.main:main`). Each command group lives in its own module."""
