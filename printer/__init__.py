"""Printer link: Marlin-protocol serial host, capability queries, virtual printer."""
